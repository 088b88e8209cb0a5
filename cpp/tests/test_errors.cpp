// Errors raised in Rust arrive in C++ as diffcassi::Error (a std::runtime_error) carrying the Rust message;
// a system stays usable after an error.
#include <diffcassi/diffcassi.hpp>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <string>

#include "check.hpp"

#ifndef DIFFCASSI_SOURCE_DIR
#define DIFFCASSI_SOURCE_DIR "."
#endif

namespace {

// Run f, expect a diffcassi::Error whose message contains every fragment.
template <class F>
void expect_error(const char* what, F&& f, std::initializer_list<const char*> fragments) {
  try {
    f();
    check::fail(std::string(what) + ": no exception", __FILE__, __LINE__);
  } catch (const diffcassi::Error& e) {
    const std::string msg = e.what();
    for (const char* frag : fragments) {
      if (msg.find(frag) == std::string::npos) check::fail(std::string(what) + ": message `" + msg + "` lacks `" + frag + "`", __FILE__, __LINE__);
    }
    std::printf("  %-28s -> %s\n", what, msg.c_str());
  } catch (const std::exception& e) {
    check::fail(std::string(what) + ": wrong exception type: " + e.what(), __FILE__, __LINE__);
  }
}

}  // namespace

int main() {
  using diffcassi::System;

  // Loading.
  expect_error("unknown preset", [] { System::preset("nope"); }, {"unknown preset `nope`", "sp, ap, msp, map"});
  expect_error("malformed TOML spec", [] { System::from_string("name = \"broken\"\nsurfaces = [", "toml", "mine.toml"); },
               {"mine.toml", "invalid TOML spec"});
  expect_error("malformed JSON spec", [] { System::from_string("{\"name\": \"x\", \"surfaces\": 3}", "auto", "mine.json"); },
               {"mine.json", "invalid JSON spec"});
  expect_error("unknown spec format", [] { System::from_string("", "xml"); }, {"unknown spec format `xml`"});
  expect_error("missing spec file", [] { System::from_file("/nonexistent/dir/system.toml"); },
               {"/nonexistent/dir/system.toml", "cannot read"});
  expect_error("non-UTF-8 text", [] { System::preset(std::string("s\xff", 2)); }, {"invalid argument"});
  {
    // Load-time warnings: none for a preset; a semi-diameter beyond a sphere's hemisphere (R = 10 mm, 12 mm) is named.
    CHECK(System::preset("sp").warnings().empty());
    const auto w = System::from_file(DIFFCASSI_SOURCE_DIR "/../tests/fixtures/systems/beyond_hemisphere.toml").warnings();
    // And its faces (R 10 mm, R -51 mm, 4 mm apart) cross at r = 7.55 mm, inside that semi-diameter (round 21).
    CHECK(w.size() == 2);
    CHECK(w[0].find("surface 1: semi-diameter 12 mm is beyond the surface's edge at r = 10 mm") != std::string::npos);
    CHECK(w[1].find("cross at r = 7.5464 mm") != std::string::npos);
    std::printf("  %-28s -> %s\n", "semi-diameter warning", w[0].c_str());
  }
  {
    // A well-formed spec naming a glass the catalogue does not have: the error names surface and glass.
    auto toml = System::preset("sp").to_toml();
    const std::string glass = "material = \"N-BK7\"";
    const auto at = toml.find(glass);
    CHECK(at != std::string::npos);
    toml.replace(at, glass.size(), "material = \"NOT-A-GLASS\"");
    expect_error("unknown glass", [&] { System::from_string(toml, "toml", "edited.toml"); }, {"NOT-A-GLASS", "surface"});
    const std::string path = "test_errors_unknown_glass.toml";
    std::ofstream(path) << toml;
    expect_error("unknown glass (file)", [&] { System::from_file(path); }, {"NOT-A-GLASS"});
    std::remove(path.c_str());
  }

  // Tracing and analyses on a valid system.
  const auto sys = System::preset("sp");
  const auto rays = sys.seeded_workload(10, {520.0}, 1);
  expect_error("unknown backend", [&] { sys.trace(rays, "warp-drive"); }, {"unknown backend `warp-drive`", "analytic"});
  expect_error("bad backend option", [&] { sys.trace(rays.columns(), "embree-mesh:0.5:fast"); }, {"refine `fast`", "f64 or none"});
  {
    auto cols = rays.columns();
    cols.dir_y = diffcassi::View<double>(cols.dir_y.data(), cols.dir_y.size() - 1);
    expect_error("column lengths differ", [&] { sys.trace(cols); }, {"different lengths", "dir_y 9"});
  }
  {
    auto buf = rays.to_buffer();
    buf.wavelength_nm[3] = 5000.0;  // far outside N-BK7's catalogue range
    expect_error("wavelength out of range", [&] { sys.trace(buf.columns()); }, {"5000"});
  }
  expect_error("distortion grid of size 0", [&] { sys.distortion_grid(520.0, 0, 2.5); }, {"at least 1"});
  expect_error("mapping cube 0 wide", [&] { sys.mapping_cube(4, 0, 0.01, {520.0}); }, {"every dimension"});
  expect_error("mapping cube too large", [&] { sys.mapping_cube(SIZE_MAX / 2, 3, 0.01, {520.0}); }, {"too large"});
  expect_error("pupil x/y lengths differ", [&] { sys.spot_diagram({0.0, 0.0}, 520.0, {0.0, 0.5}, {0.0}); }, {"pupil points"});
  expect_error("bad pupil pattern", [] { diffcassi::pupil_points("hexagonal:3"); }, {"unknown pattern"});
  expect_error("NaN field", [&] { sys.chief_rays({std::nan("")}, {0.0}, 520.0); }, {"not finite"});
  // What the CLI and Python refused and C++ took (a held-out battery, round 9): pupil points outside the unit
  // disc, a distortion grid 1e-12 mm wide, a scene 1e300 mm across, sizes beyond the memory budget (they
  // aborted the process on allocation), NaN ends of linspace, and a NUL byte in a name (its message was cut).
  expect_error("pupil point outside the disc", [&] { sys.rays_for_field({0.0, 0.0}, {2.0}, {0.0}, 520.0); }, {"px² + py² ≤ 1"});
  expect_error("spot pupil outside the disc", [&] { sys.spot_diagram({0.0, 0.0}, 520.0, {0.0, 0.0}, {0.0, 1.5}); }, {"pupil point 1", "px² + py² ≤ 1"});
  expect_error("distortion half width 1e-12", [&] { sys.distortion_grid(520.0, 5, 1e-12); }, {"half width", "[1e-3"});
  expect_error("distortion half width 1e300", [&] { sys.distortion_grid(520.0, 3, 1e300); }, {"half width"});
  expect_error("distortion grid beyond memory", [&] { sys.distortion_grid(520.0, 1u << 20, 2.5); }, {"memory"});
  expect_error("mapping cube 1e300 mm pitch", [&] { sys.mapping_cube(2, 2, 1e300, {520.0}); }, {"from the axis"});
  expect_error("mapping cube beyond memory", [&] { sys.mapping_cube(100000, 100000, 1e-4, {520.0, 600.0}); }, {"memory"});
  expect_error("seeded workload beyond memory", [&] { sys.seeded_workload(std::size_t{1} << 33, {520.0}, 0); }, {"memory"});
  expect_error("linspace beyond memory", [] { diffcassi::linspace(450.0, 650.0, std::size_t{1} << 40); }, {"memory"});
  expect_error("linspace of NaN", [] { diffcassi::linspace(0.0, std::nan(""), 3); }, {"finite"});
  expect_error("NUL in a preset name", [] { System::preset(std::string("sp\0x", 4)); }, {"NUL byte", "\\0x"});
  CHECK(diffcassi::linspace(450.0, 650.0, 3).size() == 3);

  // Jacobians: parameter names and backends.
  expect_error("unknown parameter name", [&] { sys.jacobian(rays.columns(), {"s4.tilt_q_deg"}); }, {"free parameter `s4.tilt_q_deg`", "s<N>.<column>"});
  expect_error("parameter on a missing surface", [&] { sys.jacobian(rays.columns(), {"s99.thickness_mm"}); }, {"99"});
  expect_error("unknown glass parameter", [&] { sys.jacobian(rays.columns(), {"glass_nd:UNOBTAINIUM"}); }, {"UNOBTAINIUM"});
  expect_error("no free parameters", [&] { sys.jacobian(rays.columns(), {}); }, {"no free parameters"});
  expect_error("empty parameter name", [&] { sys.jacobian(rays.columns(), {"wavelength", ""}); }, {"an empty name"});
  expect_error("comma in a parameter name", [&] { sys.jacobian(rays.columns(), {"wavelength,ray.dir_x"}); }, {"cannot contain ','"});
  expect_error("unrefined Embree Jacobian", [&] { sys.jacobian(rays.columns(), {"wavelength"}, "embree-user:none"); }, {"refine f64"});
  {
    auto cols = rays.columns();
    cols.origin_z = diffcassi::View<double>(cols.origin_z.data(), 3);
    expect_error("Jacobian column lengths differ", [&] { sys.jacobian(cols, {"wavelength"}); }, {"different lengths"});
  }

  // Renders: buffer and input sizes.
  {
    auto o = diffcassi::default_render_options();
    o.planes = 3;
    o.rays_per_pixel = 1;
    const std::vector<double> wl{500.0, 520.0, 540.0};
    std::vector<float> scene(4 * 4 * 3, 1.0f);
    const diffcassi::SceneView view{4, 4, wl, scene};
    const auto d = sys.render_detector(4, 4, wl, o);
    std::vector<double> out(d.detector_height * d.detector_width);
    expect_error("render buffer too small", [&] { sys.render_into(view, {}, o, out.data(), out.size() - 1); },
                 {"output buffer has", "render_detector"});
    std::vector<double> big(out.size() + 5);
    expect_error("render buffer too large", [&] { sys.render_into(view, {}, o, big.data(), big.size()); }, {"output buffer has"});
    const diffcassi::SceneView short_scene{4, 4, wl, diffcassi::View<float>(scene.data(), scene.size() - 2)};
    expect_error("scene size mismatch", [&] { sys.render_into(short_scene, {}, o, out.data(), out.size()); }, {"46 values for a 4×4×3 cube"});
    std::vector<float> mask(15, 1.0f);
    expect_error("mask size mismatch", [&] { sys.render_into(view, mask, o, out.data(), out.size()); }, {"the mask has 15 values", "4×4"});
    mask.assign(16, 1.0f);
    mask[5] = 2.0f;
    expect_error("mask value out of range", [&] { sys.render_into(view, mask, o, out.data(), out.size()); }, {"row 1, col 1", "[0, 1]"});
    auto bad = o;
    bad.mask_opening = 1.5;
    expect_error("mask opening out of range", [&] { sys.render_into(view, {}, bad, out.data(), out.size()); }, {"RenderOptions::mask_opening 1.5", "opening ratio"});
    bad = o;
    bad.rays_per_pixel = 0;
    expect_error("zero rays per pixel", [&] { sys.render_detector(4, 4, wl, bad); }, {"rays per pixel"});
    expect_error("rays beyond the budget", [&] {
      auto many = o;
      many.rays_per_pixel = std::size_t{1} << 40;
      sys.render_detector(4, 4, wl, many);
    }, {"rays"});
    expect_error("planes beyond the limit", [&] {
      auto many = o;
      many.planes = std::size_t{1} << 30;
      sys.render_detector(4, 4, wl, many);
    }, {"planes", "at most"});
    expect_error("scene beyond memory", [&] { sys.render_detector(100000, 100000, wl, o); }, {"memory", "raise max_memory_gb (diffcassi::set_limits)"});
    // A tolerance chooses the backend, the rays per pixel and the precision: each given beside it is refused,
    // named as C++ sets it, before any calibration; so is a tolerance that is not a positive number.
    {
      auto t = o;
      t.tolerance_um = 2.0;
      expect_error("tolerance beside rays", [&] { sys.render_detector(4, 4, wl, t); },
                   {"RenderOptions::tolerance_um 2", "RenderOptions::rays_per_pixel 1"});
      t.rays_per_pixel = 0;
      expect_error("tolerance beside a backend", [&] { sys.render_detector(4, 4, wl, t, "analytic"); },
                   {"RenderOptions::tolerance_um 2 chooses the backend", "`analytic`"});
      t.precision = diffcassi::RenderPrecision::F32;
      expect_error("tolerance beside a precision", [&] { sys.render_detector(4, 4, wl, t); },
                   {"RenderOptions::tolerance_um 2", "RenderOptions::precision f32"});
      t.precision = diffcassi::RenderPrecision::Auto;
      for (double v : {-1.0, std::nan(""), HUGE_VAL}) {
        t.tolerance_um = v;
        expect_error("tolerance not positive", [&] { sys.render_detector(4, 4, wl, t); }, {"RenderOptions::tolerance_um", "finite and > 0"});
      }
      auto p = o;
      p.precision = static_cast<diffcassi::RenderPrecision>(7);
      expect_error("precision out of the enum", [&] { sys.render_detector(4, 4, wl, p); }, {"RenderOptions::precision 7"});
      // Each setting named as C++ sets it (the library's own refusals named none; round 15).
      p = o;
      p.mask_opening = std::nan("");
      expect_error("NaN opening", [&] { sys.render_detector(4, 4, wl, p); }, {"RenderOptions::mask_opening NaN"});
      p = o;
      p.airy_diameter_px = std::nan("");
      expect_error("NaN Airy diameter", [&] { sys.render_detector(4, 4, wl, p); }, {"RenderOptions::airy_diameter_px NaN"});
      p = o;
      p.scene_pitch_mm = 0.0;
      expect_error("zero scene pitch", [&] { sys.render_detector(4, 4, wl, p); }, {"RenderOptions::scene_pitch_mm 0"});
      expect_error("scene wavelength beyond the range", [&] { sys.render_detector(4, 4, std::vector<double>{500.0, 1e9}, o); },
                   {"the scene's wavelengths_nm: 1e9 nm is outside"});
    }
    // A closed mask renders zeros, as the CLI does, and says so as the CLI warns.
    {
      auto closed = o;
      closed.mask_opening = 0.0;
      diffcassi::RenderInfo info;
      sys.render(view, {}, closed, &info);
      CHECK(info.rays_traced == 0 && info.warnings.size() == 1);
      CHECK(std::string(info.warnings[0].data(), info.warnings[0].size()).find("zero everywhere") != std::string::npos);
      sys.render(view, {}, o, &info);
      CHECK(info.warnings.empty());
    }
    // The budgets are C++'s to set: a tiny ray budget refuses a 48-ray render, naming it; the default again renders.
    diffcassi::set_limits(std::nullopt, 10.0);
    expect_error("render over a set ray budget", [&] { sys.render_detector(4, 4, wl, o); }, {"over the budget of 10 (", "max_rays (diffcassi::set_limits)"});
    expect_error("bad memory budget", [] { diffcassi::set_limits(-1.0); }, {"max_memory_gb=-1", "> 0"});
    diffcassi::set_limits();
    CHECK(sys.render_detector(4, 4, wl, o).detector_width > 0);
    {
      std::vector<float> hot(scene.size(), 3.4e38f);
      expect_error("radiance beyond the limit", [&] { sys.render_into(diffcassi::SceneView{4, 4, wl, hot}, {}, o, out.data(), out.size()); }, {"radiances must be finite, ≥ 0"});
      hot.assign(scene.size(), 1.0f);
      hot[7] = -1.0f;
      expect_error("negative radiance", [&] { sys.render_into(diffcassi::SceneView{4, 4, wl, hot}, {}, o, out.data(), out.size()); }, {"radiances must be finite, ≥ 0"});
      hot.assign(scene.size(), 1e-45f);
      expect_error("subnormal scene", [&] { sys.render_into(diffcassi::SceneView{4, 4, wl, hot}, {}, o, out.data(), out.size()); }, {"brightest value", "scale the scene's radiance up"});
    }
    auto one = o;
    one.planes = 1;
    expect_error("render wavelength out of range", [&] { sys.render_detector(4, 4, std::vector<double>{5000.0}, one); }, {"5000"});
    // After the errors the same buffer renders.
    const auto info = sys.render_into(view, {}, o, out.data(), out.size());
    CHECK(info.rays_traced > 0 && info.rays_arrived == info.rays_traced);
  }

  // Objects at infinity (issue 42): the scene's angular extent, `scene_fov_deg`, is required there, checked,
  // and refused on a finite object. A public design at infinity opened as it is (rayoptics' Cassegrain).
  {
    const auto telescope = System::from_file(DIFFCASSI_SOURCE_DIR "/../tests/fixtures/zmx/cassegrain_mirrors_HoO_V2C18Ex03.zmx");
    auto o = diffcassi::default_render_options();
    o.planes = 2;
    o.rays_per_pixel = 2;
    const std::vector<double> wl{500.0, 600.0};
    std::vector<float> scene(4 * 4 * 2, 1.0f);
    const diffcassi::SceneView view{4, 4, wl, scene};
    expect_error("no angular extent at infinity", [&] { telescope.render_detector(4, 4, wl, o); }, {"object at infinity", "scene_fov_deg"});
    for (const double bad : {180.0, -5.0, std::nan(""), HUGE_VAL}) {
      auto b = o;
      b.scene_fov_deg = bad;
      // Named as C++ sets it (the library's table of the front ends' spellings, src/frontend.rs), not `--scene-fov-deg`.
      expect_error("bad angular extent", [&] { telescope.render_detector(4, 4, wl, b); }, {"RenderOptions::scene_fov_deg", "(0, 180)"});
    }
    auto at_inf = o;
    at_inf.scene_fov_deg = 0.2;
    expect_error("angular extent on a finite object", [&] { sys.render_detector(4, 4, wl, at_inf); }, {"finite object"});
    const auto d = telescope.render_detector(4, 4, wl, at_inf);
    std::vector<double> out(d.detector_height * d.detector_width, -1.0);
    const auto info = telescope.render_into(view, {}, at_inf, out.data(), out.size());
    double total = 0.0;
    for (const double v : out) {
      CHECK(std::isfinite(v) && v >= 0.0);
      total += v;
    }
    CHECK(info.rays_arrived > 0 && total > 0.0);
  }

  // Errors are ordinary C++ exceptions, catchable as std::exception too.
  try {
    System::preset("zzz");
    CHECK(false);
  } catch (const std::exception& e) {
    CHECK(std::string(e.what()).find("unknown preset `zzz`") != std::string::npos);
  }

  // The system is still usable after all these errors.
  const auto out = sys.trace(rays);
  CHECK(out.size() == 10 && out.ok_count() == 10);

  return check::finish("test_errors");
}
