// Round 21 of the held-out battery (the C++ API at its extremes): fork() after a call, linspace's finite
// results, pupil_points as the first call, a BOM before a JSON spec string, moved-from handles, the budgets'
// range, and the thread count.
#include <diffcassi/diffcassi.hpp>

#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>
#include <utility>
#include <vector>

#include "check.hpp"

namespace {

template <class F>
void expect_error(const char* what, F&& f, std::initializer_list<const char*> fragments, std::initializer_list<const char*> absent = {}) {
  try {
    f();
    check::fail(std::string(what) + ": no exception", __FILE__, __LINE__);
  } catch (const diffcassi::Error& e) {
    const std::string msg = e.what();
    for (const char* frag : fragments)
      if (msg.find(frag) == std::string::npos) check::fail(std::string(what) + ": message `" + msg + "` lacks `" + frag + "`", __FILE__, __LINE__);
    for (const char* frag : absent)
      if (msg.find(frag) != std::string::npos) check::fail(std::string(what) + ": message `" + msg + "` has `" + frag + "`", __FILE__, __LINE__);
    std::printf("  %-28s -> %s\n", what, msg.c_str());
  } catch (const std::exception& e) {
    check::fail(std::string(what) + ": wrong exception type: " + e.what(), __FILE__, __LINE__);
  }
}

bool same_bits(const diffcassi::Traced& a, const diffcassi::Traced& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (check::bits(a.x()[i]) != check::bits(b.x()[i]) || check::bits(a.y()[i]) != check::bits(b.y()[i]) ||
        check::bits(a.dir_x()[i]) != check::bits(b.dir_x()[i]) || a.status_codes()[i] != b.status_codes()[i])
      return false;
  }
  return true;
}

// Fork; the child traces `rays` again under a 20 s alarm (the hang killed it with SIGALRM) and exits 0 when its
// result equals the parent's bit for bit (and, when threads > 0, its pool has that many threads).
void traced_in_fork_child(const char* what, const diffcassi::System& sys, const diffcassi::Rays& rays, const diffcassi::Traced& parent,
                          std::size_t threads) {
  std::fflush(nullptr);
  const pid_t pid = fork();
  if (pid < 0) {
    check::fail(std::string(what) + ": fork failed", __FILE__, __LINE__);
    return;
  }
  if (pid == 0) {
    alarm(20);
    int rc = 0;
    try {
      const auto child = sys.trace(rays);
      if (!same_bits(child, parent)) rc = 2;
      if (threads > 0 && diffcassi::get_num_threads() != threads) rc = 3;
    } catch (...) {
      rc = 4;
    }
    _exit(rc);
  }
  int status = 0;
  waitpid(pid, &status, 0);
  if (!(WIFEXITED(status) && WEXITSTATUS(status) == 0)) {
    check::fail(std::string(what) + ": the child " +
                    (WIFSIGNALED(status) ? "was killed by signal " + std::to_string(WTERMSIG(status)) + " (14: hung)"
                                         : "exited " + std::to_string(WEXITSTATUS(status)) + " (2: other bits, 3: thread count, 4: an error)"),
                __FILE__, __LINE__);
  } else {
    std::printf("  %-28s -> the child traced %zu rays, bit-identical\n", what, parent.size());
  }
}

}  // namespace

int main() {
  using diffcassi::System;

  // 4. The first call of the process: the refusal names the C++ setter, not the CLI's option.
  expect_error("pupil_points first call", [] { diffcassi::pupil_points("grid:99999999"); }, {"max_memory_gb (diffcassi::set_limits)"},
               {"--max-memory-gb"});

  // 2. fork() after a call: the child's call runs in a fresh pool (rayon's global pool has no threads there).
  {
    const auto sys = System::preset("sp");
    const auto rays = sys.seeded_workload(3000, {450.0, 650.0}, 7);
    const auto parent = sys.trace(rays);
    traced_in_fork_child("fork, default pool", sys, rays, parent, 0);
    diffcassi::set_num_threads(2);
    CHECK(diffcassi::get_num_threads() == 2);
    const auto parent2 = sys.trace(rays);
    CHECK(same_bits(parent, parent2));  // results do not depend on the thread count
    traced_in_fork_child("fork, 2-thread pool", sys, rays, parent2, 2);
    expect_error("set_num_threads(5000)", [] { diffcassi::set_num_threads(5000); }, {"diffcassi::set_num_threads(5000)", "0..=1024"});
    CHECK(diffcassi::get_num_threads() == 2);  // a refused count leaves the pool as it was
    diffcassi::set_num_threads(0);
  }

  // 3. linspace stays finite for finite ends whose difference overflows.
  {
    const auto v = diffcassi::linspace(-1e308, 1e308, 3);
    CHECK(v.size() == 3 && v[0] == -1e308 && v[1] == 0.0 && v[2] == 1e308);
    const auto w = diffcassi::linspace(-1.7e308, 1.7e308, 5);
    for (double x : w) CHECK(std::isfinite(x));
    CHECK(w.front() == -1.7e308 && w.back() == 1.7e308);
    const auto bands = diffcassi::linspace(450.0, 650.0, 28);  // the usual form's bits
    for (std::size_t i = 0; i < bands.size(); ++i) CHECK(check::bits(bands[i]) == check::bits(450.0 + (650.0 - 450.0) * double(i) / 27.0));
  }

  // 5. "auto" reads a JSON spec with a UTF-8 byte-order mark as JSON.
  {
    const std::string json = System::preset("ap").to_json();
    const auto sys = System::from_string("\xEF\xBB\xBF" + json, "auto", "bom.json");
    CHECK(sys.name() == "ap");
    const auto sys2 = System::from_string("\xEF\xBB\xBF  \n" + json);
    CHECK(sys2.name() == "ap");
  }

  // 6. A moved-from handle throws diffcassi::Error naming it, never dereferences null.
  {
    auto sys = System::preset("sp");
    auto moved = std::move(sys);
    CHECK(moved.name() == "sp");
    expect_error("moved-from System", [&] { (void)sys.name(); }, {"moved-from diffcassi::System"});
    expect_error("moved-from System trace", [&] { (void)sys.surface_count(); }, {"moved-from diffcassi::System"});
    auto t = moved.trace(moved.seeded_workload(10, {520.0}, 1));
    auto t2 = std::move(t);
    CHECK(t2.size() == 10);
    expect_error("moved-from Traced", [&] { (void)t.size(); }, {"moved-from diffcassi::Traced"});
    expect_error("moved-from Traced column", [&] { (void)t.x(); }, {"moved-from diffcassi::Traced"});
    auto r = moved.seeded_workload(4, {520.0}, 1);
    auto r2 = std::move(r);
    expect_error("moved-from Rays", [&] { (void)moved.trace(r); }, {"moved-from diffcassi::Rays"});
    t = std::move(t2);  // assigning to a moved-from handle revives it
    CHECK(t.size() == 10);
  }

  // 7. Budgets that protect nothing are refused (the CLI's and Python's checks: the library's).
  {
    const auto sys = System::preset("sp");
    expect_error("set_limits(1e300)", [] { diffcassi::set_limits(1e300); }, {"max_memory_gb=1e300", "140737"});
    expect_error("set_limits(rays 1.5)", [] { diffcassi::set_limits(std::nullopt, 1.5); }, {"max_rays=1.5", "whole number"});
    diffcassi::set_limits(140000.0);  // the largest budgets accepted: a request beyond them is still refused
    expect_error("seeded_workload(2^41)", [&] { (void)sys.seeded_workload(std::size_t(1) << 41, {520.0}, 0); }, {"seeded workload", "max_memory_gb"});
    diffcassi::set_limits();
  }

  // 1. A Jacobian is checked against the memory budget before its N × K values are allocated.
  {
    const auto sys = System::preset("sp");
    const auto big = sys.seeded_workload(5000, {520.0, 600.0}, 3);
    diffcassi::set_limits(0.001);  // 1 MB: 10⁴ rays × 3 parameters need ≈ 5.6 MB
    expect_error("jacobian over the budget", [&] { (void)sys.jacobian(big.columns(), {"prism_tilt_x", "wavelength", "s4.thickness_mm"}); },
                 {"Jacobian of N × K = 10000 rays × 3 parameters", "reduce the rays or the parameters", "max_memory_gb (diffcassi::set_limits)"});
    const auto small = sys.seeded_workload(50, {520.0}, 3);
    const auto j = sys.jacobian(small.columns(), {"prism_tilt_x", "wavelength", "s4.thickness_mm"});  // 50 rays fit
    CHECK(j.size() == 50 && j.parameter_count() == 3);
    diffcassi::set_limits();
  }

  return check::finish("test_round21");
}
