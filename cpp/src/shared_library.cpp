// The shared library libdiffcassi.so is the Rust static library (with the cxx bridge's C++ side inside)
// linked whole, exporting only the C++ API and cxx's C++ runtime (cmake/diffcassi.map). A library needs a
// source of its own; this one also checks that the generated header compiles on its own.
#include "diffcassi/bridge.h"
