// C++ results equal the Rust API's, bit for bit.
//
// The reference file is written by a separate Rust program that uses only the `diffcassi` crate (not the
// bridge): cpp/bridge/examples/cpp_reference.rs. For every preset it holds a ray batch (seeded workload,
// rays aimed outside the pupil, a backwards ray, a NaN origin, a zero direction) with its trace, a 13x13
// grid distortion, a mapping cube, a spot diagram, the batch's Jacobians for five parameters named as C++
// names them (analytic and Embree hits) and three small renders (a random mask from opening and seed, in f64
// and in f32; an explicit mask), every double as its bit pattern in hex. This program rebuilds the batch in C++-owned
// std::vectors, traces it through the C++ API, runs the same analyses, Jacobians and renders (scene and
// mask filled in C++ by the reference's formulas), and compares every value's bits.
//
//   test_bitwise <reference file>
#include <diffcassi/diffcassi.hpp>

#include <fstream>
#include <iostream>
#include <sstream>

#include "check.hpp"

namespace {

std::ifstream in;

std::string word() {
  std::string s;
  if (!(in >> s)) throw std::runtime_error("reference file ended early");
  return s;
}
double hexd() { return check::from_hex(word()); }
long long integer() { return std::stoll(word()); }
void expect(const std::string& keyword) {
  const std::string w = word();
  if (w != keyword) throw std::runtime_error("reference file: expected `" + keyword + "`, found `" + w + "`");
}

struct Counter {
  std::size_t values = 0, mismatches = 0;
  void same(double cpp, double rust, const std::string& what) {
    ++values;
    if (check::bits(cpp) != check::bits(rust)) {
      if (++mismatches <= 10) {
        std::ostringstream m;
        m.precision(17);
        m << what << ": C++ " << cpp << " vs Rust " << rust;
        check::fail(m.str(), __FILE__, __LINE__);
      } else {
        ++check::failures();
      }
    }
  }
  void same_int(long long cpp, long long rust, const std::string& what) {
    ++values;
    if (cpp != rust) {
      ++mismatches;
      check::fail(what + ": C++ " + std::to_string(cpp) + " vs Rust " + std::to_string(rust), __FILE__, __LINE__);
    }
  }
};

// ---- Jacobians of the batch: traced values, availability and the SoA derivatives.
std::pair<std::size_t, std::size_t> run_jacobian(const diffcassi::System& sys, const std::string& preset, const diffcassi::RayBuffer& rays) {
  expect("jacobian");
  const std::string backend = word();
  const auto kk = static_cast<std::size_t>(integer());
  std::vector<std::string> names(kk);
  for (auto& n : names) n = word();
  const auto n = static_cast<std::size_t>(integer());
  const auto j = sys.jacobian(rays.columns(), names, backend);
  Counter c;
  const std::string at0 = preset + " jacobian " + backend;
  CHECK(j.size() == n && j.parameter_count() == kk && j.values().size() == 6 * kk * n);
  const auto canonical = j.parameters();
  for (std::size_t k = 0; k < kk; ++k) {
    const std::string name = word();
    if (k < canonical.size() && canonical[k] != name) check::fail(at0 + ": parameter " + canonical[k] + " vs Rust " + name, __FILE__, __LINE__);
  }
  std::size_t available = 0;
  for (std::size_t i = 0; i < n && i < j.size(); ++i) {
    const std::string at = at0 + " ray " + std::to_string(i);
    c.same(j.x()[i], hexd(), at + " x");
    c.same(j.y()[i], hexd(), at + " y");
    c.same(j.z()[i], hexd(), at + " z");
    c.same(j.dir_x()[i], hexd(), at + " dir_x");
    c.same(j.dir_y()[i], hexd(), at + " dir_y");
    c.same(j.dir_z()[i], hexd(), at + " dir_z");
    c.same_int(j.status_codes()[i], integer(), at + " status");
    c.same_int(j.available(i), integer(), at + " available");
    available += j.available(i);
    // An unavailable ray says why; an available one has no reason.
    if (j.available(i) != j.reason(i).empty()) check::fail(at + ": reason `" + j.reason(i) + "`", __FILE__, __LINE__);
  }
  for (std::size_t comp = 0; comp < 6; ++comp)
    for (std::size_t k = 0; k < kk; ++k) {
      const auto col = j.column(comp, k);
      for (std::size_t i = 0; i < n; ++i) c.same(col[i], hexd(), at0 + " d" + std::to_string(comp) + "/d" + names[k] + " ray " + std::to_string(i));
    }
  CHECK(available > n / 2);
  return {c.values, c.mismatches};
}

// ---- a render into a caller buffer: scene and mask filled here by the reference's formulas.
std::pair<std::size_t, std::size_t> run_render(const diffcassi::System& sys, const std::string& preset) {
  expect("render");
  const std::string backend = word();
  const std::string precision = word();
  const auto h = static_cast<std::size_t>(integer()), w = static_cast<std::size_t>(integer()), nb = static_cast<std::size_t>(integer());
  auto o = diffcassi::default_render_options();
  o.precision = precision == "f32" ? diffcassi::RenderPrecision::F32 : diffcassi::RenderPrecision::F64;
  o.planes = static_cast<std::size_t>(integer());
  o.rays_per_pixel = static_cast<std::size_t>(integer());
  o.seed = static_cast<std::uint64_t>(integer());
  const bool explicit_mask = integer() == 1;
  o.mask_opening = hexd();
  o.mask_seed = static_cast<std::uint64_t>(integer());
  std::vector<double> wl(nb);
  for (auto& v : wl) v = hexd();
  std::vector<float> scene(h * w * nb), mask;
  for (std::size_t q = 0; q < scene.size(); ++q) {
    const std::size_t r = q / nb / w, col = (q / nb) % w, b = q % nb;
    scene[q] = static_cast<float>(0.25 + 0.05 * static_cast<double>((r * 7 + col * 3 + b * 5) % 11));
  }
  if (explicit_mask) {
    const float levels[3] = {0.0f, 0.5f, 1.0f};
    for (std::size_t q = 0; q < h * w; ++q) mask.push_back(levels[(q / w + 2 * (q % w)) % 3]);
  }
  const diffcassi::SceneView view{h, w, wl, scene};
  const auto d = sys.render_detector(h, w, wl, o, backend);
  Counter c;
  const std::string at = preset + " render " + backend + " " + precision + (explicit_mask ? " explicit mask" : " random mask");
  c.same_int(static_cast<long long>(d.detector_height), integer(), at + " detector height");
  c.same_int(static_cast<long long>(d.detector_width), integer(), at + " detector width");
  c.same(d.detector_pitch_mm, hexd(), at + " pitch");
  c.same(d.x_left_mm, hexd(), at + " x_left");
  c.same(d.y_top_mm, hexd(), at + " y_top");
  std::vector<double> image(d.detector_height * d.detector_width, -1.0);  // the caller's buffer
  const auto info = sys.render_into(view, mask, o, image.data(), image.size(), backend);
  c.same_int(static_cast<long long>(info.rays_traced), integer(), at + " rays traced");
  c.same_int(static_cast<long long>(info.rays_arrived), integer(), at + " rays arrived");
  // What traced it, as the options gave it.
  CHECK(info.precision == o.precision && info.rays_per_pixel == o.rays_per_pixel && info.predicted_error_um == 0.0);
  CHECK(std::string(info.tracer.data(), info.tracer.size()).rfind(backend, 0) == 0);
  double total = 0;
  for (std::size_t q = 0; q < image.size(); ++q) {
    c.same(image[q], hexd(), at + " pixel " + std::to_string(q));
    total += image[q];
  }
  CHECK(total > 0.0 && info.rays_traced > 0);
  return {c.values, c.mismatches};
}

void run_case(const std::string& preset) {
  const auto sys = diffcassi::System::preset(preset);

  // ---- trace: the batch as C++-owned columns, read in place by the tracer
  expect("rays");
  const auto n = static_cast<std::size_t>(integer());
  diffcassi::RayBuffer rays;
  rays.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    const double ox = hexd(), oy = hexd(), oz = hexd(), dx = hexd(), dy = hexd(), dz = hexd(), w = hexd();
    rays.push({ox, oy, oz}, {dx, dy, dz}, w);
  }
  const auto out = sys.trace(rays.columns(), "analytic");
  expect("traced");
  const auto m = static_cast<std::size_t>(integer());
  expect("ok");
  const auto ok = integer();
  Counter trace;
  trace.same_int(static_cast<long long>(out.size()), static_cast<long long>(m), preset + " traced size");
  trace.same_int(static_cast<long long>(out.ok_count()), ok, preset + " ok count");
  CHECK(out.size() == m);
  std::size_t failed_kinds[6] = {0, 0, 0, 0, 0, 0};
  for (std::size_t i = 0; i < m && i < out.size(); ++i) {
    const std::string at = preset + " ray " + std::to_string(i);
    trace.same(out.x()[i], hexd(), at + " x");
    trace.same(out.y()[i], hexd(), at + " y");
    trace.same(out.z()[i], hexd(), at + " z");
    trace.same(out.dir_x()[i], hexd(), at + " dir_x");
    trace.same(out.dir_y()[i], hexd(), at + " dir_y");
    trace.same(out.dir_z()[i], hexd(), at + " dir_z");
    trace.same_int(out.status_codes()[i], integer(), at + " status");
    trace.same_int(out.surface()[i], integer(), at + " surface");
    if (out.status_codes()[i] < 6) ++failed_kinds[out.status_codes()[i]];
  }
  // The batch must exercise failures too, or the comparison of status/surface proves little.
  CHECK(failed_kinds[0] > 0);
  CHECK(failed_kinds[static_cast<int>(diffcassi::RayStatus::InvalidInput)] == 2);
  CHECK(failed_kinds[1] + failed_kinds[2] > 0);

  // ---- grid distortion
  expect("distortion");
  const double w = hexd();
  const auto gn = static_cast<std::size_t>(integer());
  const double half = hexd();
  const auto g = sys.distortion_grid(w, gn, half);
  Counter dist;
  dist.same(g.reference_mm[0], hexd(), preset + " Xref");
  dist.same(g.reference_mm[1], hexd(), preset + " Yref");
  for (int k = 0; k < 4; ++k) dist.same(g.abcd[k], hexd(), preset + " abcd");
  dist.same(g.max_distortion_pct, hexd(), preset + " max distortion");
  CHECK(g.points.size() == gn * gn);
  for (std::size_t k = 0; k < gn * gn && k < g.points.size(); ++k) {
    const auto& p = g.points[k];
    const std::string at = preset + " grid point " + std::to_string(k);
    dist.same_int(p.i, integer(), at + " i");
    dist.same_int(p.j, integer(), at + " j");
    dist.same(p.x_field_mm, hexd(), at + " x_field");
    dist.same(p.y_field_mm, hexd(), at + " y_field");
    dist.same(p.real_x_mm, hexd(), at + " real_x");
    dist.same(p.real_y_mm, hexd(), at + " real_y");
    dist.same(p.pred_x_mm, hexd(), at + " pred_x");
    dist.same(p.pred_y_mm, hexd(), at + " pred_y");
    dist.same(p.distortion_pct, hexd(), at + " distortion");
    dist.same_int(p.status, integer(), at + " status");
  }

  // ---- mapping cube
  expect("mapping");
  const auto h = static_cast<std::size_t>(integer());
  const auto wd = static_cast<std::size_t>(integer());
  const double pitch = hexd();
  const auto nl = static_cast<std::size_t>(integer());
  std::vector<double> wl(nl);
  for (auto& v : wl) v = hexd();
  const auto cube = sys.mapping_cube(h, wd, pitch, wl);
  Counter map;
  CHECK(cube.height() == h && cube.width() == wd && cube.wavelength_nm().size() == nl);
  CHECK(cube.positions_mm().size() == 2 * h * wd * nl && cube.valid().size() == h * wd * nl);
  for (std::size_t k = 0; k < h * wd * nl && k < cube.valid().size(); ++k) {
    const std::string at = preset + " mapping entry " + std::to_string(k);
    map.same(cube.positions_mm()[2 * k], hexd(), at + " x");
    map.same(cube.positions_mm()[2 * k + 1], hexd(), at + " y");
    map.same_int(cube.valid()[k], integer(), at + " valid");
  }

  // ---- spot diagram
  expect("spot");
  const double fx = hexd(), fy = hexd(), sw = hexd();
  const auto np = static_cast<std::size_t>(integer());
  std::vector<double> px(np), py(np), sx(np), sy(np);
  std::vector<long long> ss(np);
  for (std::size_t k = 0; k < np; ++k) {
    px[k] = hexd();
    py[k] = hexd();
    sx[k] = hexd();
    sy[k] = hexd();
    ss[k] = integer();
  }
  const auto spot = sys.spot_diagram({fx, fy}, sw, px, py);
  Counter sp;
  CHECK(spot.x_mm().size() == np);
  for (std::size_t k = 0; k < np && k < spot.x_mm().size(); ++k) {
    sp.same(spot.x_mm()[k], sx[k], preset + " spot x");
    sp.same(spot.y_mm()[k], sy[k], preset + " spot y");
    sp.same_int(spot.status_codes()[k], ss[k], preset + " spot status");
  }
  const auto st = spot.stats();
  CHECK(st.valid && spot.has_chief());
  sp.same_int(static_cast<long long>(st.count), integer(), preset + " spot count");
  sp.same(st.centroid_x_mm, hexd(), preset + " centroid x");
  sp.same(st.centroid_y_mm, hexd(), preset + " centroid y");
  sp.same(st.rms_radius_um, hexd(), preset + " rms");
  sp.same(st.geo_radius_um, hexd(), preset + " geo");
  sp.same(spot.chief_mm()[0], hexd(), preset + " chief x");
  sp.same(spot.chief_mm()[1], hexd(), preset + " chief y");
  sp.same(spot.rms_radius_chief_um(), hexd(), preset + " rms about chief");

  std::size_t jv = 0, jm = 0, rv = 0, rm = 0;
  for (int b = 0; b < 2; ++b) {
    const auto r = run_jacobian(sys, preset, rays);
    jv += r.first;
    jm += r.second;
  }
  for (int b = 0; b < 3; ++b) {
    const auto r = run_render(sys, preset);
    rv += r.first;
    rm += r.second;
  }
  std::printf("%-3s  jacobians (analytic, embree-user): %zu values, %zu differ | renders (random mask f64 and f32, explicit mask): %zu values, %zu differ\n",
              preset.c_str(), jv, jm, rv, rm);
  std::printf("%-3s  trace: %zu rays (%zu ok, %zu missed, %zu vignetted, %zu invalid), %zu values, %zu differ | "
              "distortion: %zu values, %zu differ | mapping: %zu values, %zu differ | spot: %zu values, %zu differ\n",
              preset.c_str(), out.size(), failed_kinds[0], failed_kinds[1], failed_kinds[2], failed_kinds[5], trace.values,
              trace.mismatches, dist.values, dist.mismatches, map.values, map.mismatches, sp.values, sp.mismatches);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s <reference file from cpp_reference>\n", argv[0]);
    return 2;
  }
  in.open(argv[1]);
  if (!in) {
    std::fprintf(stderr, "cannot open %s (run: cargo run --release -p diffcassi-cpp --example cpp_reference -- %s)\n", argv[1], argv[1]);
    return 2;
  }
  try {
    expect("diffcassi-cpp-reference");
    expect("1");
    int cases = 0;
    for (std::string w = word(); w != "end"; w = word()) {
      if (w != "case") throw std::runtime_error("reference file: expected `case`, found `" + w + "`");
      run_case(word());
      ++cases;
    }
    CHECK(cases == 4);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "FAIL: %s\n", e.what());
    return 1;
  }
  return check::finish("test_bitwise");
}
