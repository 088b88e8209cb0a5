// Overhead of the C++ API: trace throughput through C++ (System::trace on C++-owned std::vector columns)
// against the Rust API (Tracer::trace timed inside Rust, no FFI in the loop), on the same workload as the
// Rust example cpp/bridge/examples/trace_throughput.rs: SP, 4 wavelengths, seeded pupil points over the
// four fields, 1e3 and 1e6 rays. C++ and Rust calls alternate in blocks so that load changes on a shared
// machine hit both alike. Prints a Markdown table.
//
//   bench_trace [--quick]
#include <diffcassi/diffcassi.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <thread>
#include <vector>

namespace {

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  const bool quick = argc > 1 && std::strcmp(argv[1], "--quick") == 0;
  const auto sys = diffcassi::System::preset("sp");
  const std::vector<double> wavelengths = {450.0, 520.0, 585.0, 650.0};

  std::printf("C++ API vs Rust API, backend analytic, preset sp (%u hardware threads)\n", std::thread::hardware_concurrency());
  std::printf("| rays | reps (each) | Rust median ms/trace | C++ median ms/trace | Rust M rays/s | C++ M rays/s | C++ vs Rust |\n");
  std::printf("|---|---|---|---|---|---|---|\n");
  struct Size {
    std::size_t rays, blocks, per_block;
  };
  const Size sizes[] = {{1000, quick ? 2u : 20u, quick ? 10u : 100u}, {1000000, quick ? 1u : 15u, 1}};
  for (const auto& s : sizes) {
    const auto rays = sys.seeded_workload(s.rays / wavelengths.size(), wavelengths, 7);
    const auto buffer = rays.to_buffer();  // C++-owned columns, read in place by the tracer
    const auto columns = buffer.columns();

    // Same results either way (the bit-identity test checks this thoroughly).
    const auto a = sys.trace(columns);
    const auto b = sys.trace(rays);
    if (a.size() != b.size() || std::memcmp(a.x().data(), b.x().data(), a.size() * sizeof(double)) != 0) {
      std::fprintf(stderr, "C++ and Rust traces differ\n");
      return 1;
    }
    sys.time_rust_trace(rays, 1);  // warm-up

    std::vector<double> t_cpp, t_rust;
    for (std::size_t blk = 0; blk < s.blocks; ++blk) {
      for (std::size_t r = 0; r < s.per_block; ++r) {
        const auto t0 = std::chrono::steady_clock::now();
        const auto out = sys.trace(columns);
        const auto t1 = std::chrono::steady_clock::now();
        if (out.size() != s.rays) return 1;
        t_cpp.push_back(std::chrono::duration<double>(t1 - t0).count());
      }
      const auto rust = sys.time_rust_trace(rays, s.per_block);
      t_rust.insert(t_rust.end(), rust.begin(), rust.end());
    }
    const double mc = median(t_cpp), mr = median(t_rust);
    std::printf("| %zu | %zu | %.4f | %.4f | %.3f | %.3f | %+.2f %% |\n", s.rays, t_cpp.size(), 1e3 * mr, 1e3 * mc, s.rays / mr / 1e6,
                s.rays / mc / 1e6, 100.0 * (mc / mr - 1.0));
  }
  return 0;
}
