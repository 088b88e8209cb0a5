// The learned denoiser from C++ (diffcassi::denoise): a denoised cube of the input's size, finite, repeatable
// bit for bit, equal with the embedded and the committed weights file; wrong sizes, band counts, σ and
// weights files throw diffcassi::Error naming the problem.
#include <diffcassi/diffcassi.hpp>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include "check.hpp"

#ifndef DIFFCASSI_SOURCE_DIR
#define DIFFCASSI_SOURCE_DIR "."
#endif

namespace {

template <class F>
void expect_error(const char* what, F&& f, const char* fragment) {
  try {
    f();
    check::fail(std::string(what) + ": no exception", __FILE__, __LINE__);
  } catch (const diffcassi::Error& e) {
    const std::string msg = e.what();
    if (msg.find(fragment) == std::string::npos) check::fail(std::string(what) + ": `" + msg + "` lacks `" + fragment + "`", __FILE__, __LINE__);
    std::printf("  %-20s -> %s\n", what, msg.c_str());
  }
}

}  // namespace

int main() {
  const std::size_t h = 14, w = 10, b = 28;
  std::vector<float> cube(h * w * b);
  for (std::size_t i = 0; i < cube.size(); ++i) cube[i] = 0.5f + 0.3f * std::sin(0.01f * static_cast<float>(i)) + ((i * 7919) % 13 == 0 ? 0.05f : 0.0f);
  const auto a = diffcassi::denoise(cube, h, w, b, 0.05);
  CHECK(a.size() == cube.size());
  bool finite = true, changed = false, same = true;
  for (std::size_t i = 0; i < a.size(); ++i) {
    finite = finite && std::isfinite(a[i]);
    changed = changed || a[i] != cube[i];
  }
  CHECK(finite);
  CHECK(changed);
  const auto again = diffcassi::denoise(cube, h, w, b, 0.05, DIFFCASSI_SOURCE_DIR "/../src/recon/prior/weights/spectral-unet-v2-28.safetensors");
  for (std::size_t i = 0; i < a.size(); ++i) same = same && check::bits(a[i]) == check::bits(again[i]);
  CHECK(same);

  expect_error("wrong band count", [&] { diffcassi::denoise(diffcassi::View<float>(cube.data(), h * w * 4), h, w, 4, 0.05); }, "trained for 28 bands");
  expect_error("wrong size", [&] { diffcassi::denoise(diffcassi::View<float>(cube.data(), 10), h, w, b, 0.05); }, "needs");
  expect_error("NaN sigma", [&] { diffcassi::denoise(cube, h, w, b, std::nan("")); }, "sigma");
  // σ as given, not its f32 conversion (1e300 was reported as "σ = inf"; round 9).
  expect_error("sigma beyond f32", [&] { diffcassi::denoise(cube, h, w, b, 1e300); }, "sigma = 1e300");
  expect_error("missing weights", [&] { diffcassi::denoise(cube, h, w, b, 0.05, "/nonexistent/w.safetensors"); }, "/nonexistent/w.safetensors");
  {
    const std::string path = "test_denoise_bad.safetensors";
    std::ofstream(path) << "not weights";
    expect_error("corrupt weights", [&] { diffcassi::denoise(cube, h, w, b, 0.05, path); }, "not a valid safetensors file");
    std::remove(path.c_str());
  }
  if (check::failures()) return 1;
  std::printf("denoise: OK\n");
  return 0;
}
