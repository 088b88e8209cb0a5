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
  std::printf("| rays | calls each | Rust best ms | C++ best ms | C++ vs Rust (best) | Rust median ms | C++ median ms | C++ vs Rust (median of paired ratios) |\n");
  std::printf("|---|---|---|---|---|---|---|---|\n");
  struct Size {
    std::size_t rays, blocks, per_block;
  };
  // Calls alternate C++/Rust in blocks (1e3: blocks of 50 calls; 1e6: single calls), so that both see the
  // same machine load; "paired ratio" = C++ block time / the Rust block right after it.
  const Size sizes[] = {{1000, quick ? 2u : 80u, quick ? 10u : 50u}, {1000000, quick ? 1u : 25u, 1}};
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

    std::vector<double> t_cpp, t_rust, ratios;
    for (std::size_t blk = 0; blk < s.blocks; ++blk) {
      double block_cpp = 0.0, block_rust = 0.0;
      for (std::size_t r = 0; r < s.per_block; ++r) {
        const auto t0 = std::chrono::steady_clock::now();
        const auto out = sys.trace(columns);
        const auto t1 = std::chrono::steady_clock::now();
        if (out.size() != s.rays) return 1;
        t_cpp.push_back(std::chrono::duration<double>(t1 - t0).count());
        block_cpp += t_cpp.back();
      }
      for (double t : sys.time_rust_trace(rays, s.per_block)) {
        t_rust.push_back(t);
        block_rust += t;
      }
      ratios.push_back(block_cpp / block_rust);
    }
    const double bc = *std::min_element(t_cpp.begin(), t_cpp.end()), br = *std::min_element(t_rust.begin(), t_rust.end());
    std::printf("| %zu | %zu | %.4f | %.4f | %+.2f %% | %.4f | %.4f | %+.2f %% |\n", s.rays, t_cpp.size(), 1e3 * br, 1e3 * bc,
                100.0 * (bc / br - 1.0), 1e3 * median(t_rust), 1e3 * median(t_cpp), 100.0 * (median(ratios) - 1.0));
  }
  return 0;
}
