// diffcassi C++ API: the idiomatic wrapper over the generated cxx bridge (diffcassi/bridge.h).
//
// C++17. RAII handles (move-only; the Rust objects are freed when they go out of scope; a moved-from handle
// may only be destroyed or assigned to: any other use throws diffcassi::Error "use of a moved-from
// diffcassi::System", never dereferences a null pointer), read-only
// span-like views of Rust-owned columns (no copy out), caller-owned input columns read in place (no copy
// in), and exceptions: every error raised in Rust arrives as diffcassi::Error whose what() is the Rust
// message (e.g. "unknown preset `xyz` (presets: sp, ap, msp, map, gsp, ddsp, mddsp)").
//
//   #include <diffcassi/diffcassi.hpp>
//   auto sys  = diffcassi::System::preset("sp");
//   auto grid = sys.distortion_grid(520.0, 13, 2.5);          // Zemax-style grid distortion
//   auto rays = sys.seeded_workload(1000, {450.0, 650.0}, 7);   // or your own columns, see RayColumns
//   auto out  = sys.trace(rays.columns());                     // backend "analytic" by default
//   for (std::size_t i = 0; i < out.size(); ++i)
//     if (out.status(i) == diffcassi::RayStatus::Ok) use(out.x()[i], out.y()[i]);
//
// Units: mm, nm, degrees (as in the Rust crate and its spec files).
//
// Thread safety: a System is immutable once loaded; every member function is const and may be called
// concurrently from several threads on one System (tests/test_threads.cpp). Traces run on the library's
// rayon thread pool and their results do not depend on which thread called or how many threads run
// (set_num_threads, else RAYON_NUM_THREADS or all cores). fork(): a child process's calls build a fresh pool
// of the same size (the parent's threads do not exist in the child), so a pre-fork server may trace in its
// parent and then in its workers; results are the same bits.
// Result objects (Traced, Spot, Mapping, Rays) are independent values: read them from any thread.
//
// Also: Jacobians (free parameters by name, SoA derivatives in one allocation; System::jacobian) and
// rendering a coded acquisition into a caller buffer (System::render_detector + System::render_into).
// Backends by name: "analytic", "embree-user[:f64|:none]", "embree-mesh[:SAG_UM][:f64|:none]".
#pragma once

#include "rust/cxx.h"  // cxx's runtime (rust::Error, …); shares include guards with the generated header
#include "diffcassi/bridge.h"

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace diffcassi {

/// Every error raised by the library; what() carries the Rust message.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A read-only, non-owning view of contiguous elements (std::span<const T> in C++20 terms).
template <class T>
class View {
 public:
  constexpr View() noexcept = default;
  constexpr View(const T* data, std::size_t size) noexcept : data_(data), size_(size) {}
  View(rust::Slice<const T> s) noexcept : data_(s.data()), size_(s.size()) {}  // NOLINT: implicit by design
  View(const std::vector<T>& v) noexcept : data_(v.data()), size_(v.size()) {}  // NOLINT

  const T* data() const noexcept { return data_; }
  std::size_t size() const noexcept { return size_; }
  bool empty() const noexcept { return size_ == 0; }
  const T* begin() const noexcept { return data_; }
  const T* end() const noexcept { return data_ + size_; }
  const T& operator[](std::size_t i) const noexcept { return data_[i]; }
  const T& at(std::size_t i) const {
    if (i >= size_) throw std::out_of_range("diffcassi::View index " + std::to_string(i) + " >= size " + std::to_string(size_));
    return data_[i];
  }
  std::vector<T> to_vector() const { return std::vector<T>(begin(), end()); }

 private:
  const T* data_ = nullptr;
  std::size_t size_ = 0;
};

/// Outcome of one ray (the values of Rust's diffcassi::tracer::RayStatus).
enum class RayStatus : std::uint8_t {
  Ok = 0,
  Missed = 1,
  Vignetted = 2,
  TotalInternalReflection = 3,
  NoConvergence = 4,
  InvalidInput = 5,
  /// Non-sequential (Embree) backends: absorbed by a side wall, or over the bounce limit.
  Absorbed = 6,
  BounceLimit = 7,
  /// Arrived at a non-finite or implausible position (beyond 1e6 mm): an overflow, not a result.
  OutOfRange = 8,
};

inline const char* label(RayStatus s) noexcept {
  switch (s) {
    case RayStatus::Ok: return "ok";
    case RayStatus::Missed: return "missed";
    case RayStatus::Vignetted: return "vignetted";
    case RayStatus::TotalInternalReflection: return "tir";
    case RayStatus::NoConvergence: return "no_convergence";
    case RayStatus::InvalidInput: return "invalid_input";
    case RayStatus::Absorbed: return "absorbed";
    case RayStatus::BounceLimit: return "bounce_limit";
    case RayStatus::OutOfRange: return "out_of_range";
  }
  return "unknown";
}

using SurfaceInfo = ffi::SurfaceInfo;
using SpotStats = ffi::SpotStats;
using DistortionPoint = ffi::DistortionPoint;
using DistortionGrid = ffi::DistortionGrid;
using RenderOptions = ffi::RenderOptions;
using RenderInfo = ffi::RenderInfo;
using RenderPrecision = ffi::RenderPrecision;

namespace detail {
// Run a bridge call; a Rust error (rust::Error) or text that is not UTF-8 (rust::Str) becomes diffcassi::Error.
template <class F>
auto call(F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (const rust::Error& e) {
    throw Error(e.what());
  } catch (const std::invalid_argument& e) {
    throw Error(std::string("invalid argument: ") + e.what());
  }
}
// The object behind a handle, or diffcassi::Error when the handle was moved from (its Box is then null): a
// moved-from System, Traced, … dereferenced a null pointer and crashed with SIGSEGV (round 21).
template <class T>
const T& live(const rust::Box<T>& box, const char* type) {
  const T* p = box.operator->();
  if (p == nullptr)
    throw Error(std::string("use of a moved-from diffcassi::") + type + ": its contents were moved into another " + type +
                "; use that one (a moved-from handle may only be destroyed or assigned to)");
  return *p;
}
inline rust::Str str(std::string_view s) { return rust::Str(s.data(), s.size()); }
template <class T>
rust::Slice<const T> slice(View<T> v) noexcept { return rust::Slice<const T>(v.data(), v.size()); }
template <class T>
rust::Slice<const T> slice(const std::vector<T>& v) noexcept { return rust::Slice<const T>(v.data(), v.size()); }
inline std::string string(const rust::String& s) { return std::string(s.data(), s.size()); }
inline std::vector<std::string> strings(const rust::Vec<rust::String>& v) {
  std::vector<std::string> out;
  out.reserve(v.size());
  for (const auto& s : v) out.push_back(string(s));
  return out;
}
}  // namespace detail

/// Rays in object space as caller-owned columns (mm, directions need not be unit, nm), struct of arrays.
/// The library reads them in place; all seven must have the same length (else diffcassi::Error).
struct RayColumns {
  View<double> origin_x, origin_y, origin_z;
  View<double> dir_x, dir_y, dir_z;
  View<double> wavelength_nm;
  std::size_t size() const noexcept { return origin_x.size(); }
};

/// A simple owning struct-of-arrays container for rays built in C++.
struct RayBuffer {
  std::vector<double> origin_x, origin_y, origin_z, dir_x, dir_y, dir_z, wavelength_nm;
  void reserve(std::size_t n) {
    for (auto* v : {&origin_x, &origin_y, &origin_z, &dir_x, &dir_y, &dir_z, &wavelength_nm}) v->reserve(n);
  }
  void push(std::array<double, 3> origin, std::array<double, 3> direction, double wavelength) {
    origin_x.push_back(origin[0]);
    origin_y.push_back(origin[1]);
    origin_z.push_back(origin[2]);
    dir_x.push_back(direction[0]);
    dir_y.push_back(direction[1]);
    dir_z.push_back(direction[2]);
    wavelength_nm.push_back(wavelength);
  }
  std::size_t size() const noexcept { return origin_x.size(); }
  RayColumns columns() const { return {origin_x, origin_y, origin_z, dir_x, dir_y, dir_z, wavelength_nm}; }
};

/// Rays made by the library (aimed as the system says). Views stay valid while this object lives.
class Rays {
 public:
  explicit Rays(rust::Box<ffi::Rays> raw) : raw_(std::move(raw)) {}
  std::size_t size() const { return get().len(); }
  View<double> origin_x() const { return get().origin_x(); }
  View<double> origin_y() const { return get().origin_y(); }
  View<double> origin_z() const { return get().origin_z(); }
  View<double> dir_x() const { return get().dir_x(); }
  View<double> dir_y() const { return get().dir_y(); }
  View<double> dir_z() const { return get().dir_z(); }
  View<double> wavelength_nm() const { return get().wavelength_nm(); }
  RayColumns columns() const { return {origin_x(), origin_y(), origin_z(), dir_x(), dir_y(), dir_z(), wavelength_nm()}; }
  /// A C++-owned copy.
  RayBuffer to_buffer() const {
    return {origin_x().to_vector(), origin_y().to_vector(), origin_z().to_vector(), dir_x().to_vector(),
            dir_y().to_vector(),    dir_z().to_vector(),    wavelength_nm().to_vector()};
  }
  const ffi::Rays& raw() const { return get(); }

 private:
  const ffi::Rays& get() const { return detail::live(raw_, "Rays"); }
  rust::Box<ffi::Rays> raw_;
};

/// A traced batch in the image surface's frame: positions (mm), unit directions, status, and for failed
/// rays the surface where they stopped (their positions/directions are 0, never NaN). The columns are the
/// tracer's own result buffers, viewed without copying; they stay valid while this object lives.
class Traced {
 public:
  explicit Traced(rust::Box<ffi::Traced> raw) : raw_(std::move(raw)) {}
  std::size_t size() const { return get().len(); }
  std::size_t ok_count() const { return get().ok_count(); }
  View<double> x() const { return get().x(); }
  View<double> y() const { return get().y(); }
  View<double> z() const { return get().z(); }
  View<double> dir_x() const { return get().dir_x(); }
  View<double> dir_y() const { return get().dir_y(); }
  View<double> dir_z() const { return get().dir_z(); }
  /// RayStatus values as bytes.
  View<std::uint8_t> status_codes() const { return get().status(); }
  RayStatus status(std::size_t i) const { return static_cast<RayStatus>(status_codes().at(i)); }
  /// Surface index where a failed ray stopped (0xFFFFFFFF for arrived rays).
  View<std::uint32_t> surface() const { return get().surface(); }
  const ffi::Traced& raw() const { return get(); }

 private:
  const ffi::Traced& get() const { return detail::live(raw_, "Traced"); }
  rust::Box<ffi::Traced> raw_;
};

/// A spot diagram of one field and wavelength.
class Spot {
 public:
  explicit Spot(rust::Box<ffi::Spot> raw) : raw_(std::move(raw)) {}
  std::array<double, 2> field_mm() const { return get().field_mm(); }
  double wavelength_nm() const { return get().wavelength_nm(); }
  View<double> x_mm() const { return get().x_mm(); }
  View<double> y_mm() const { return get().y_mm(); }
  View<std::uint8_t> status_codes() const { return get().status(); }
  bool has_chief() const { return get().has_chief(); }
  /// Chief-ray position (mm); (0, 0) when !has_chief().
  std::array<double, 2> chief_mm() const { return get().chief_mm(); }
  SpotStats stats() const { return get().stats(); }
  double rms_radius_chief_um() const { return get().rms_radius_chief_um(); }
  const ffi::Spot& raw() const { return get(); }

 private:
  const ffi::Spot& get() const { return detail::live(raw_, "Spot"); }
  rust::Box<ffi::Spot> raw_;
};

/// The scene → detector mapping cube f(x_s, y_s, λ) = (x_d, y_d): chief rays of every scene pixel centre.
class Mapping {
 public:
  explicit Mapping(rust::Box<ffi::Mapping> raw) : raw_(std::move(raw)) {}
  std::size_t height() const { return get().height(); }
  std::size_t width() const { return get().width(); }
  double pixel_pitch_mm() const { return get().pixel_pitch_mm(); }
  View<double> wavelength_nm() const { return get().wavelength_nm(); }
  /// Detector (x, y) mm, C order [row][col][band][xy]; 0 where valid() is 0.
  View<double> positions_mm() const { return get().positions_mm(); }
  /// 1 where the chief ray arrived, C order [row][col][band].
  View<std::uint8_t> valid() const { return get().valid(); }
  std::size_t invalid_count() const { return get().invalid_count(); }
  std::size_t index(std::size_t row, std::size_t col, std::size_t band) const {
    return (row * width() + col) * wavelength_nm().size() + band;
  }
  bool valid(std::size_t row, std::size_t col, std::size_t band) const { return valid().at(index(row, col, band)) == 1; }
  std::array<double, 2> position_mm(std::size_t row, std::size_t col, std::size_t band) const {
    const std::size_t k = index(row, col, band);
    return {positions_mm().at(2 * k), positions_mm().at(2 * k + 1)};
  }
  const ffi::Mapping& raw() const { return get(); }

 private:
  const ffi::Mapping& get() const { return detail::live(raw_, "Mapping"); }
  rust::Box<ffi::Mapping> raw_;
};

/// Jacobians of a traced batch: d(x, y, z, dir_x, dir_y, dir_z at the image surface)/d(parameter k) for
/// N rays and K free parameters, struct of arrays in one allocation: values()[(c * K + k) * N + i], so the
/// derivatives of one output component by one parameter are contiguous over the rays (column(c, k)).
/// Units: mm (positions) or direction components, per unit of the parameter (mm, degrees, nm, …).
/// Rays whose Jacobian is unavailable (did not arrive; with an Embree backend also a path that is not the
/// sequential one, e.g. a followed total internal reflection) have zeros and a reason.
class Jacobian {
 public:
  /// Output components, in the order of the c index.
  enum Component : std::size_t { X = 0, Y = 1, Z = 2, DirX = 3, DirY = 4, DirZ = 5 };
  explicit Jacobian(rust::Box<ffi::Jacobian> raw) : raw_(std::move(raw)) {}
  std::size_t size() const { return get().len(); }
  std::size_t parameter_count() const { return get().parameter_count(); }
  /// Canonical parameter names in column order (aliases such as prism_tilt_x resolved to s<N>.<column>).
  std::vector<std::string> parameters() const {
    std::vector<std::string> out;
    for (const auto& s : get().parameters()) out.push_back(detail::string(s));
    return out;
  }
  View<double> values() const { return get().values(); }
  /// d(component c)/d(parameter k) for every ray.
  View<double> column(std::size_t c, std::size_t k) const {
    const std::size_t n = size(), kk = parameter_count();
    if (c >= 6 || k >= kk) throw Error("Jacobian::column(" + std::to_string(c) + ", " + std::to_string(k) + "): out of range");
    return View<double>(values().data() + (c * kk + k) * n, n);
  }
  double at(std::size_t ray, std::size_t c, std::size_t k) const { return column(c, k).at(ray); }
  bool available(std::size_t i) const { return View<std::uint8_t>(get().available()).at(i) == 1; }
  View<std::uint8_t> available_flags() const { return get().available(); }
  /// Why ray i's Jacobian is unavailable ("" if it is available).
  std::string reason(std::size_t i) const { return std::string(get().reason(i)); }
  // The traced values (as Traced's columns).
  View<double> x() const { return get().traced_x(); }
  View<double> y() const { return get().traced_y(); }
  View<double> z() const { return get().traced_z(); }
  View<double> dir_x() const { return get().traced_dir_x(); }
  View<double> dir_y() const { return get().traced_dir_y(); }
  View<double> dir_z() const { return get().traced_dir_z(); }
  View<std::uint8_t> status_codes() const { return get().traced_status(); }
  RayStatus status(std::size_t i) const { return static_cast<RayStatus>(status_codes().at(i)); }
  const ffi::Jacobian& raw() const { return get(); }

 private:
  const ffi::Jacobian& get() const { return detail::live(raw_, "Jacobian"); }
  rust::Box<ffi::Jacobian> raw_;
};

/// The paper's render settings (4 planes per band, 20 rays per pixel, seed 0, 10 µm pixels, Airy 2.5 px at
/// 520 nm, random mask of opening 0.5, seed 0, precision Auto: f64, no tolerance); change the fields you need.
/// For the speed/accuracy choice (the CLI's --tolerance-um), set tolerance_um (µm) and rays_per_pixel = 0 and
/// leave the backend argument empty: the render's RenderInfo says what was chosen.
inline RenderOptions default_render_options() { return ffi::default_render_options(); }

/// A hyperspectral scene held by the caller: height × width × bands floats, C order [row][col][band]
/// (row 0 at +y on the object plane), at strictly increasing band wavelengths (nm). Read in place.
struct SceneView {
  std::size_t height = 0, width = 0;
  View<double> wavelengths_nm;
  View<float> values;
};

/// A loaded optical system. Immutable and thread-safe (see the top of this header).
class System {
 public:
  /// One of the presets "sp", "ap", "msp", "map", "gsp", "ddsp", "mddsp" (case-insensitive).
  static System preset(std::string_view name) {
    return System(detail::call([&] { return ffi::load_preset(detail::str(name)); }));
  }
  /// A spec file: .toml/.json (diffcassi's format), .yml (the paper's), .csv (Zemax prescription), .zmx (a Zemax
  /// lens file).
  static System from_file(std::string_view path) {
    return System(detail::call([&] { return ffi::load_spec_file(detail::str(path)); }));
  }
  /// A spec held in memory; format "toml", "json" or "auto" (JSON when the first non-blank character, after an
  /// optional UTF-8 byte-order mark, is `{`); source_name names it in error messages.
  static System from_string(std::string_view text, std::string_view format = "auto", std::string_view source_name = "<string>") {
    return System(detail::call([&] { return ffi::load_spec_string(detail::str(text), detail::str(format), detail::str(source_name)); }));
  }

  std::string name() const { return std::string(get().name()); }
  std::string description() const { return std::string(get().description()); }
  /// The resolved Lens Data Editor (pickups and solves evaluated), surface 0 = object.
  rust::Vec<SurfaceInfo> surfaces() const { return get().surfaces(); }
  std::size_t surface_count() const { return get().surface_count(); }
  /// Load-time warnings (the CLI prints them when it loads the system, Python raises them as UserWarnings):
  /// glasses whose catalogue contradicts itself, semi-diameters beyond a surface's edge. Empty for a spec
  /// as its author meant it.
  std::vector<std::string> warnings() const { return detail::strings(get().warnings()); }
  std::size_t stop_index() const { return get().stop_index(); }
  View<double> wavelengths_nm() const { return get().wavelengths_nm(); }
  double primary_wavelength_nm() const { return get().primary_wavelength_nm(); }
  std::vector<std::array<double, 2>> fields_mm() const {
    const auto flat = get().fields_mm();
    std::vector<std::array<double, 2>> out;
    for (std::size_t i = 0; i + 1 < flat.size(); i += 2) out.push_back({flat[i], flat[i + 1]});
    return out;
  }
  std::size_t surfaces_per_ray() const { return get().surfaces_per_ray(); }
  std::string to_toml() const { return detail::string(detail::call([&] { return get().to_toml(); })); }
  std::string to_json() const { return detail::string(detail::call([&] { return get().to_json(); })); }

  // ---- rays
  /// Rays of one field point (mm) through normalised pupil points (px, py) at one wavelength (nm).
  Rays rays_for_field(std::array<double, 2> field_mm, const std::vector<double>& px, const std::vector<double>& py, double wavelength_nm) const {
    return Rays(detail::call([&] { return get().rays_for_field(field_mm[0], field_mm[1], detail::slice(px), detail::slice(py), wavelength_nm); }));
  }
  Rays chief_rays(const std::vector<double>& field_x_mm, const std::vector<double>& field_y_mm, double wavelength_nm) const {
    return Rays(detail::call([&] { return get().chief_rays(detail::slice(field_x_mm), detail::slice(field_y_mm), wavelength_nm); }));
  }
  /// A reproducible workload: rays_per_wavelength rays per wavelength over the system's fields, pupil
  /// points uniform in the disk from a ChaCha8 stream seeded with seed + wavelength index.
  Rays seeded_workload(std::size_t rays_per_wavelength, const std::vector<double>& wavelengths_nm, std::uint64_t seed) const {
    return Rays(detail::call([&] { return get().seeded_workload(rays_per_wavelength, detail::slice(wavelengths_nm), seed); }));
  }

  // ---- tracing
  /// Trace caller-owned columns (read in place) with a backend ("analytic"; see backend_names()).
  Traced trace(const RayColumns& r, std::string_view backend = "analytic") const {
    return Traced(detail::call([&] {
      return get().trace(detail::str(backend), detail::slice(r.origin_x), detail::slice(r.origin_y), detail::slice(r.origin_z),
                         detail::slice(r.dir_x), detail::slice(r.dir_y), detail::slice(r.dir_z), detail::slice(r.wavelength_nm));
    }));
  }
  Traced trace(const Rays& rays, std::string_view backend = "analytic") const {
    return Traced(detail::call([&] { return get().trace_rays(detail::str(backend), rays.raw()); }));
  }
  /// Bench helper: seconds per trace of `rays`, timed natively in Rust around Tracer::trace, reps times.
  std::vector<double> time_rust_trace(const Rays& rays, std::size_t reps, std::string_view backend = "analytic") const {
    const auto t = detail::call([&] { return get().time_rust_trace(detail::str(backend), rays.raw(), reps); });
    return std::vector<double>(t.begin(), t.end());
  }

  // ---- analyses
  Spot spot_diagram(std::array<double, 2> field_mm, double wavelength_nm, const std::vector<double>& px, const std::vector<double>& py,
                    std::string_view backend = "analytic") const {
    return Spot(detail::call([&] {
      return get().spot_diagram(detail::str(backend), field_mm[0], field_mm[1], wavelength_nm, detail::slice(px), detail::slice(py));
    }));
  }
  /// Zemax-style Grid Distortion: n × n chief rays over ±half_width_mm of object field.
  DistortionGrid distortion_grid(double wavelength_nm, std::size_t n, double half_width_mm, std::string_view backend = "analytic") const {
    return detail::call([&] { return get().distortion_grid(detail::str(backend), wavelength_nm, n, half_width_mm); });
  }
  /// The H × W × Nλ mapping cube (scene pixel centres on a pixel_pitch_mm grid, row 0 at +y).
  Mapping mapping_cube(std::size_t height, std::size_t width, double pixel_pitch_mm, const std::vector<double>& wavelengths_nm,
                       std::string_view backend = "analytic") const {
    return Mapping(detail::call([&] { return get().mapping_cube(detail::str(backend), height, width, pixel_pitch_mm, detail::slice(wavelengths_nm)); }));
  }

  // ---- Jacobians
  /// Trace `rays` with d(image position, direction)/d(parameters): `parameters` are the names
  /// `diffcassi calibrate --free` takes ("s4.tilt_x_deg", "s16.curvature", "glass_nd:N-BK7",
  /// "glass_vd:N-SF10", "wavelength", "ray.origin_x", "ray.dir_y", and on presets "prism_tilt_x|y|z").
  /// Backend "analytic", or "embree-user" / "embree-mesh[:SAG_UM]" (f64-refined hits; the derivatives
  /// are taken at Embree's hits). An unknown name throws diffcassi::Error.
  Jacobian jacobian(const RayColumns& r, const std::vector<std::string>& parameters, std::string_view backend = "analytic") const {
    std::string list;
    for (const auto& p : parameters) {
      if (p.find(',') != std::string::npos) throw Error("free parameter `" + p + "`: a name cannot contain ','");
      if (!list.empty()) list += ',';
      list += p;
    }
    return Jacobian(detail::call([&] {
      return get().trace_jacobian(detail::str(backend), detail::str(list), detail::slice(r.origin_x), detail::slice(r.origin_y),
                                  detail::slice(r.origin_z), detail::slice(r.dir_x), detail::slice(r.dir_y), detail::slice(r.dir_z),
                                  detail::slice(r.wavelength_nm));
    }));
  }

  // ---- rendering
  /// The detector a render of a height × width scene at these band wavelengths produces: size the output
  /// buffer render_into needs as detector_height * detector_width doubles.
  /// An empty backend: analytic, or the choice of options.tolerance_um.
  RenderInfo render_detector(std::size_t height, std::size_t width, const View<double>& wavelengths_nm, const RenderOptions& options,
                             std::string_view backend = "") const {
    return detail::call([&] { return get().render_detector(detail::str(backend), height, width, detail::slice(wavelengths_nm), options); });
  }
  /// Render the coded acquisition of `scene` through the mask (height × width transmissions in [0, 1];
  /// an empty view: the random mask of options.mask_opening / mask_seed) into `out` (row-major detector
  /// image, exactly render_detector's size, else diffcassi::Error). Returns the detector, the ray counts and
  /// what traced them (tracer, rays per pixel, precision; a tolerance's predicted error).
  RenderInfo render_into(const SceneView& scene, View<float> mask, const RenderOptions& options, double* out, std::size_t out_size,
                         std::string_view backend = "") const {
    return detail::call([&] {
      return get().render(detail::str(backend), scene.height, scene.width, detail::slice(scene.wavelengths_nm), detail::slice(scene.values),
                          detail::slice(mask), options, rust::Slice<double>(out, out_size));
    });
  }
  /// render_detector + render_into into a new vector.
  std::vector<double> render(const SceneView& scene, View<float> mask, const RenderOptions& options, RenderInfo* info = nullptr,
                             std::string_view backend = "") const {
    const auto d = render_detector(scene.height, scene.width, scene.wavelengths_nm, options, backend);
    std::vector<double> out(d.detector_height * d.detector_width);
    const auto done = render_into(scene, mask, options, out.data(), out.size(), backend);
    if (info) *info = done;
    return out;
  }

  const ffi::System& raw() const { return get(); }

 private:
  const ffi::System& get() const { return detail::live(raw_, "System"); }
  explicit System(rust::Box<ffi::System> raw) : raw_(std::move(raw)) {}
  rust::Box<ffi::System> raw_;
};

inline std::vector<std::string> preset_names() { return detail::strings(ffi::preset_names()); }
/// Every backend name trace() accepts (Embree ones take options, see diffcassi::tracer::BackendConfig).
inline std::vector<std::string> backend_names() { return detail::strings(ffi::backend_names()); }
inline std::string version() { return detail::string(ffi::version()); }
/// "chief", "marginal", "hexapolar:R", "grid:N", "grid-step:S", "random:N:SEED".
struct PupilPoints {
  std::vector<double> px, py;
  std::size_t size() const noexcept { return px.size(); }
};
inline PupilPoints pupil_points(std::string_view pattern) {
  const auto p = detail::call([&] { return ffi::pupil_points(detail::str(pattern)); });
  return {std::vector<double>(p.px.begin(), p.px.end()), std::vector<double>(p.py.begin(), p.py.end())};
}
/// The learned denoiser (spectral-unet-v2, the prior of the pnp-gap / pnp-admm solvers) on a cube of
/// height × width × bands floats, C order [row][col][band]; sigma: the noise standard deviation on the cube's
/// scale (trained on cubes of peak ≈ 1); weights: a safetensors file, empty for the embedded checkpoint.
/// Returns the denoised cube (same layout). Throws diffcassi::Error on a wrong size, band count or weights.
inline std::vector<float> denoise(View<float> cube, std::size_t height, std::size_t width, std::size_t bands, double sigma,
                                  std::string_view weights = {}) {
  std::vector<float> out(cube.size());
  detail::call([&] {
    ffi::denoise(detail::slice(cube), height, width, bands, sigma, detail::str(weights), rust::Slice<float>(out.data(), out.size()));
  });
  return out;
}

/// The memory budget (GB, > 0 and at most 140737, the 2^47 bytes a 64-bit process can address) and the ray
/// budget (a whole number of rays, ≥ 1) of every following call, process-wide (the CLI's --max-memory-gb /
/// --max-rays, Python's diffcassi.set_limits, with the same checks); std::nullopt: the default (half of the
/// physical memory; 2e10 rays). Both are replaced at each call; a bad value throws and leaves them as they were.
inline void set_limits(std::optional<double> max_memory_gb = std::nullopt, std::optional<double> max_rays = std::nullopt) {
  detail::call([&] { ffi::set_limits(max_memory_gb.has_value(), max_memory_gb.value_or(0.0), max_rays.has_value(), max_rays.value_or(0.0)); });
}

/// The threads of every following call, process-wide (the CLI's --threads, Python's diffcassi.set_num_threads):
/// 1..=1024, or 0 for the default (RAYON_NUM_THREADS, else all cores). Results do not depend on it.
inline void set_num_threads(std::size_t n) {
  detail::call([&] { ffi::set_num_threads(n); });
}
/// The threads the following calls use.
inline std::size_t get_num_threads() {
  return detail::call([&] { return ffi::get_num_threads(); });
}

/// The folder of the render tolerance's calibration cache (RenderOptions::tolerance_um; the CLI's
/// --calibration-cache) for every following call; empty: the default ($DIFFCASSI_CACHE_DIR, else
/// $XDG_CACHE_HOME/diffcassi, else ~/.cache/diffcassi). A path that exists and is not a folder is refused.
inline void set_calibration_cache(std::string_view dir = "") {
  detail::call([&] { ffi::set_calibration_cache(detail::str(dir)); });
}

/// `count` evenly spaced values from `first` to `last` (both included); non-finite ends, or a count beyond the
/// memory budget, throw diffcassi::Error.
inline std::vector<double> linspace(double first, double last, std::size_t count) {
  const auto v = detail::call([&] { return ffi::linspace(first, last, count); });
  return std::vector<double>(v.begin(), v.end());
}

}  // namespace diffcassi
