// Minimal test helpers for the C++ tests (no framework: each test is a program; ctest runs it and a
// non-zero exit status fails it).
#pragma once

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

namespace check {

inline int& failures() {
  static int n = 0;
  return n;
}

inline void fail(const std::string& what, const char* file, int line) {
  std::fprintf(stderr, "FAIL %s:%d: %s\n", file, line, what.c_str());
  ++failures();
}

/// The IEEE-754 bit pattern of a double (bit-identity comparisons: distinguishes -0 from 0, compares NaNs).
inline std::uint64_t bits(double v) {
  std::uint64_t b;
  std::memcpy(&b, &v, sizeof b);
  return b;
}

inline double from_hex(const std::string& s) {
  const std::uint64_t b = std::strtoull(s.c_str(), nullptr, 16);
  double v;
  std::memcpy(&v, &b, sizeof v);
  return v;
}

inline int finish(const char* name) {
  if (failures() == 0) {
    std::printf("%s: PASS\n", name);
    return 0;
  }
  std::printf("%s: %d FAILURES\n", name, failures());
  return 1;
}

}  // namespace check

#define CHECK(cond)                                                   \
  do {                                                                \
    if (!(cond)) ::check::fail(std::string("CHECK(") + #cond + ")", __FILE__, __LINE__); \
  } while (0)
