// Thread safety: several std::threads trace concurrently on ONE loaded System (and compute grid
// distortions, Jacobians and small renders, and hit errors) and every result equals, bit for bit, the same
// call made alone beforehand.
#include <diffcassi/diffcassi.hpp>

#include <atomic>
#include <cstring>
#include <thread>
#include <vector>

#include "check.hpp"

namespace {

bool same_bits(diffcassi::View<double> a, diffcassi::View<double> b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(double)) == 0;
}

bool same(const diffcassi::Traced& a, const diffcassi::Traced& b) {
  return same_bits(a.x(), b.x()) && same_bits(a.y(), b.y()) && same_bits(a.z(), b.z()) && same_bits(a.dir_x(), b.dir_x()) &&
         same_bits(a.dir_y(), b.dir_y()) && same_bits(a.dir_z(), b.dir_z()) && a.status_codes().size() == b.status_codes().size() &&
         std::memcmp(a.status_codes().data(), b.status_codes().data(), a.status_codes().size()) == 0 &&
         std::memcmp(a.surface().data(), b.surface().data(), a.surface().size() * sizeof(std::uint32_t)) == 0;
}

bool same(const diffcassi::DistortionGrid& a, const diffcassi::DistortionGrid& b) {
  if (a.points.size() != b.points.size()) return false;
  for (std::size_t k = 0; k < a.points.size(); ++k) {
    const auto &p = a.points[k], &q = b.points[k];
    if (check::bits(p.real_x_mm) != check::bits(q.real_x_mm) || check::bits(p.real_y_mm) != check::bits(q.real_y_mm) ||
        check::bits(p.distortion_pct) != check::bits(q.distortion_pct) || p.status != q.status)
      return false;
  }
  return check::bits(a.abcd[0]) == check::bits(b.abcd[0]) && check::bits(a.max_distortion_pct) == check::bits(b.max_distortion_pct);
}

}  // namespace

int main() {
  constexpr int kThreads = 6;
  constexpr int kIterations = 8;
  const auto sys = diffcassi::System::preset("map");

  // Per-thread workloads (different seeds and wavelengths), C++-owned, with their single-call results.
  std::vector<diffcassi::RayBuffer> batches;
  std::vector<diffcassi::Traced> expected;
  for (int t = 0; t < kThreads; ++t) {
    batches.push_back(sys.seeded_workload(3000 + 500 * t, {450.0 + 20.0 * t, 610.0}, 100 + t).to_buffer());
    expected.push_back(sys.trace(batches.back().columns()));
    CHECK(expected.back().ok_count() > 0);
  }
  const auto expected_grid = sys.distortion_grid(520.0, 13, 2.5);
  // A Jacobian of a small batch and a small render, each made alone first.
  const auto jac_rays = sys.seeded_workload(200, {480.0, 600.0}, 9).to_buffer();
  const std::vector<std::string> params{"prism_tilt_x", "glass_nd:N-SK2", "wavelength"};
  const auto expected_jac = sys.jacobian(jac_rays.columns(), params).values().to_vector();
  auto ro = diffcassi::default_render_options();
  ro.planes = 4;
  ro.rays_per_pixel = 2;
  const std::vector<double> rwl{500.0, 540.0};
  std::vector<float> rscene(8 * 8 * 2);
  for (std::size_t q = 0; q < rscene.size(); ++q) rscene[q] = static_cast<float>(q % 7) * 0.25f;
  const diffcassi::SceneView rview{8, 8, rwl, rscene};
  const auto expected_render = sys.render(rview, {}, ro);

  std::atomic<int> traces{0}, grids{0}, jacobians{0}, renders{0}, errors{0}, wrong{0};
  std::vector<std::thread> pool;
  for (int t = 0; t < kThreads; ++t) {
    pool.emplace_back([&, t] {
      for (int it = 0; it < kIterations; ++it) {
        const auto out = sys.trace(batches[t].columns());
        ++traces;
        if (!same(out, expected[t])) ++wrong;
        if ((t + it) % 3 == 0) {
          if (!same(sys.distortion_grid(520.0, 13, 2.5), expected_grid)) ++wrong;
          ++grids;
        }
        if ((t + it) % 4 == 2) {
          const auto j = sys.jacobian(jac_rays.columns(), params);
          if (!same_bits(j.values(), expected_jac)) ++wrong;
          ++jacobians;
        }
        if ((t + it) % 4 == 3) {
          if (!same_bits(sys.render(rview, {}, ro), expected_render)) ++wrong;
          ++renders;
        }
        if ((t + it) % 4 == 1) {
          try {
            sys.trace(batches[t].columns(), "no-such-backend");
          } catch (const diffcassi::Error&) {
            ++errors;
          }
        }
      }
    });
  }
  for (auto& th : pool) th.join();
  std::printf("%d threads on one System: %d traces, %d distortion grids, %d Jacobians, %d renders, %d errors caught, %d results differ "
              "from the sequential ones\n",
              kThreads, traces.load(), grids.load(), jacobians.load(), renders.load(), errors.load(), wrong.load());
  CHECK(wrong.load() == 0);
  CHECK(traces.load() == kThreads * kIterations);
  CHECK(errors.load() > 0);
  CHECK(jacobians.load() > 0 && renders.load() > 0);

  // Loading concurrently is safe too (independent systems).
  std::vector<std::thread> loaders;
  std::atomic<int> loaded{0};
  for (int t = 0; t < 4; ++t)
    loaders.emplace_back([&, t] {
      const auto s = diffcassi::System::preset(diffcassi::preset_names()[t]);
      if (s.surface_count() > 0) ++loaded;
    });
  for (auto& th : loaders) th.join();
  CHECK(loaded.load() == 4);

  return check::finish("test_threads");
}
