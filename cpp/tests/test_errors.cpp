// Errors raised in Rust arrive in C++ as diffcassi::Error (a std::runtime_error) carrying the Rust message;
// a system stays usable after an error.
#include <diffcassi/diffcassi.hpp>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <string>

#include "check.hpp"

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
