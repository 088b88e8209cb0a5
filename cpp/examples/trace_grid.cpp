// Trace the 13x13 distortion grid of a preset and print it as CSV on stdout: the same columns and number
// format as `diffcassi distortion --csv` (shortest text that parses back to the same double).
//
//   trace_grid [preset=sp] [wavelength_nm=primary] [grid=13] [half_width_mm=2.5] [backend=analytic]
#include <diffcassi/diffcassi.hpp>

#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

namespace {

// Rust's `{}` for f64 within [1e-4, 1e15) and `{:e}` outside, as diffcassi's CSV writer does.
std::string number(double x) {
  char buf[64];
  const double a = std::fabs(x);
  const bool plain = x == 0.0 || (a >= 1e-4 && a < 1e15);
  auto r = std::to_chars(buf, buf + sizeof buf, x, plain ? std::chars_format::fixed : std::chars_format::scientific);
  std::string s(buf, r.ptr);
  if (!plain) {  // C++ writes 1.5e-05 / 1e+15, Rust 1.5e-5 / 1e15
    const auto e = s.find('e');
    std::string mant = s.substr(0, e), exp = s.substr(e + 1);
    const bool neg = exp[0] == '-';
    if (exp[0] == '+' || exp[0] == '-') exp.erase(0, 1);
    exp.erase(0, std::min(exp.find_first_not_of('0'), exp.size() - 1));
    s = mant + "e" + (neg ? "-" : "") + exp;
  }
  return s;
}

// Rust's `{}` for f64 (shortest round-trip digits, never an exponent), used in the comment lines.
std::string display(double x) {
  char buf[400];
  auto r = std::to_chars(buf, buf + sizeof buf, x, std::chars_format::fixed);
  return std::string(buf, r.ptr);
}

}  // namespace

int main(int argc, char** argv) {
  try {
    const std::string preset = argc > 1 ? argv[1] : "sp";
    const auto sys = diffcassi::System::preset(preset);
    const double wavelength = argc > 2 ? std::strtod(argv[2], nullptr) : sys.primary_wavelength_nm();
    const std::size_t n = argc > 3 ? std::strtoul(argv[3], nullptr, 10) : 13;
    const double half = argc > 4 ? std::strtod(argv[4], nullptr) : 2.5;
    const std::string backend = argc > 5 ? argv[5] : "analytic";

    const auto g = sys.distortion_grid(wavelength, n, half, backend);
    std::printf("# system %s; wavelength %s nm; positions absolute in the image surface's frame (mm)\n", sys.name().c_str(),
                display(g.wavelength_nm).c_str());
    std::printf("# reference (on-axis chief ray) Xref_mm=%s Yref_mm=%s\n", display(g.reference_mm[0]).c_str(), display(g.reference_mm[1]).c_str());
    std::printf("# predicted = ref + ABCD·field, A=%s B=%s C=%s D=%s; max distortion %s%%\n", display(g.abcd[0]).c_str(),
                display(g.abcd[1]).c_str(), display(g.abcd[2]).c_str(), display(g.abcd[3]).c_str(), display(g.max_distortion_pct).c_str());
    std::printf("i,j,x_field_mm,y_field_mm,r_field_mm,pred_x_mm,pred_y_mm,real_x_mm,real_y_mm,distortion_pct,status\n");
    for (const auto& p : g.points) {
      const auto status = static_cast<diffcassi::RayStatus>(p.status);
      const bool ok = status == diffcassi::RayStatus::Ok;
      std::printf("%d,%d,%s,%s,%s,%s,%s,%s,%s,%s,%s\n", p.i, p.j, number(p.x_field_mm).c_str(), number(p.y_field_mm).c_str(),
                  number(std::hypot(p.x_field_mm, p.y_field_mm)).c_str(), number(p.pred_x_mm).c_str(), number(p.pred_y_mm).c_str(),
                  ok ? number(p.real_x_mm).c_str() : "", ok ? number(p.real_y_mm).c_str() : "", ok ? number(p.distortion_pct).c_str() : "",
                  diffcassi::label(status));
    }
    return 0;
  } catch (const diffcassi::Error& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
