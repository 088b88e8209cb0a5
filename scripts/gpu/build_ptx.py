#!/usr/bin/env python3
"""Compile diffcassi's CUDA kernels (src/gpu/kernels/device.cu) to PTX with NVRTC and assemble them with ptxas.

No GPU is needed: NVRTC (PyPI `nvidia-cuda-nvrtc`) compiles for a virtual architecture, and ptxas (PyPI
`nvidia-cuda-nvcc`) assembles the PTX for a real one, so compile errors, register counts and spills show on any
machine. Both at CUDA 13.0 (scripts/setup.sh puts them in .venv/cuda-ptx): a driver takes the PTX ISA of its
own CUDA version and older ones, and the GPU machine's driver (580.159) is CUDA 13.0, ISA 9.0; NVRTC 13.2
(torch's) writes ISA 9.2, which it refuses.

    python scripts/gpu/build_ptx.py            # check: compile, assemble for sm_90, print registers and
                                               # spills; fail if the committed trace.ptx is stale
    python scripts/gpu/build_ptx.py --write    # also (re)write the committed src/gpu/kernels/trace.ptx

The committed PTX starts with a comment naming the SHA-256 of the kernel sources it was built from; the
library embeds it (src/gpu/ptx.rs), so a build needs no CUDA at all. Options: --fmad=false (no
contraction: the device computes the same bits as the host twin), --prec-sqrt=true --prec-div=true --ftz=false
(NVRTC's defaults, stated: the f32 kernels need IEEE sqrtf and division and subnormals), compute_90 (H100/H200; the driver
JIT-compiles it for any later architecture).
"""
import argparse
import ctypes
import glob
import hashlib
import os
import re
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
KERNELS = os.path.join(ROOT, "src", "gpu", "kernels")
SOURCES = ["dc_common.h", "dc_vec_tmpl.h", "dc_trace.h", "dc_trace_tmpl.h", "dc_sample.h", "dc_render.h", "dc_accum.h", "device.cu"]
PTX = os.path.join(KERNELS, "trace.ptx")
ARCH = "compute_90"
OPTIONS = [f"--gpu-architecture={ARCH}", "--fmad=false", "--prec-sqrt=true", "--prec-div=true", "--ftz=false", "-default-device"]


def source_hash():
    h = hashlib.sha256()
    for name in SOURCES:
        with open(os.path.join(KERNELS, name), "rb") as f:
            h.update(name.encode() + b"\0" + f.read() + b"\0")
    return h.hexdigest()


def site_dirs():
    import site
    dirs = list(site.getsitepackages()) + [site.getusersitepackages()]
    return [d for d in dirs if os.path.isdir(d)]


# NVRTC and ptxas at the GPU machine's CUDA version, installed by scripts/setup.sh.
PINNED = os.path.join(ROOT, ".venv", "cuda-ptx")


def find_tool(env, subpath, name_re, fallbacks, usable):
    """A CUDA tool: $env if set, else the newest match of nvidia/*/<subpath> in .venv/cuda-ptx (the pinned
    CUDA 13.0 wheels), else in the venv's site-packages, else the first usable fallback (a system CUDA)."""
    if os.environ.get(env):
        return os.environ[env]
    for d in [PINNED] + site_dirs():
        found = sorted(f for f in glob.glob(os.path.join(d, "nvidia", "*", subpath)) if re.search(name_re, f))
        if found:
            return found[-1]
    return next((c for c in fallbacks if usable(c)), None)


def loadable(lib):
    try:
        ctypes.CDLL(lib)
        return True
    except OSError:
        return False


def find_nvrtc():
    return find_tool("DIFFCASSI_NVRTC", os.path.join("lib", "libnvrtc.so.*"), r"libnvrtc\.so\.\d+$",
                     ["libnvrtc.so", "/usr/local/cuda/lib64/libnvrtc.so"], loadable)


def find_ptxas():
    return find_tool("DIFFCASSI_PTXAS", os.path.join("bin", "ptxas"), r"ptxas$", ["/usr/local/cuda/bin/ptxas"],
                     lambda c: os.access(c, os.X_OK))


def amalgamated():
    """device.cu with every `#include "…"` replaced by the file's text where it stands (the guarded headers skip
    themselves, the templates expand per include): what gpu::ptx::amalgamated_source gives the launcher's
    NVRTC fallback and the GPU check's `nvcc -ptx`."""
    def expand(name, depth):
        if depth > 16:
            sys.exit("build_ptx: kernel includes nested too deep")
        out = []
        with open(os.path.join(KERNELS, name)) as f:
            for line in f.read().splitlines():
                m = re.fullmatch(r'\s*#include "([^"]+)"\s*', line)
                out.extend(expand(m.group(1), depth + 1) if m else [line])
        return out
    return ("\n".join(expand("device.cu", 0)) + "\n").encode()


def nvrtc_compile(lib_path, src=None):
    # NVRTC opens its builtins library by name: load the one beside it first (a --target install is on no
    # loader path).
    for builtins in sorted(glob.glob(os.path.join(os.path.dirname(lib_path), "libnvrtc-builtins.so.*"))):
        if ".alt." not in builtins:
            ctypes.CDLL(builtins, mode=ctypes.RTLD_GLOBAL)
    lib = ctypes.CDLL(lib_path)
    major, minor = ctypes.c_int(), ctypes.c_int()
    lib.nvrtcVersion(ctypes.byref(major), ctypes.byref(minor))
    if src is None:
        with open(os.path.join(KERNELS, "device.cu"), "rb") as f:
            src = f.read()
    prog = ctypes.c_void_p()
    err = lib.nvrtcCreateProgram(ctypes.byref(prog), ctypes.c_char_p(src), b"device.cu", 0, None, None)
    if err != 0:
        sys.exit(f"build_ptx: nvrtcCreateProgram failed ({err})")
    opts = OPTIONS + [f"--include-path={KERNELS}"]
    arr = (ctypes.c_char_p * len(opts))(*[o.encode() for o in opts])
    err = lib.nvrtcCompileProgram(prog, len(opts), arr)
    size = ctypes.c_size_t()
    lib.nvrtcGetProgramLogSize(prog, ctypes.byref(size))
    log = ctypes.create_string_buffer(size.value)
    lib.nvrtcGetProgramLog(prog, log)
    text = log.value.decode(errors="replace").strip()
    if err != 0:
        sys.exit(f"build_ptx: NVRTC failed to compile device.cu:\n{text}")
    if text:
        print(f"build_ptx: NVRTC log:\n{text}")
    lib.nvrtcGetPTXSize(prog, ctypes.byref(size))
    ptx = ctypes.create_string_buffer(size.value)
    lib.nvrtcGetPTX(prog, ptx)
    lib.nvrtcDestroyProgram(ctypes.byref(prog))
    return ptx.value.decode(), f"{major.value}.{minor.value}"


def header(digest, version):
    return (f"// diffcassi: generated by scripts/gpu/build_ptx.py from src/gpu/kernels ({', '.join(SOURCES)}); do not edit.\n"
            f"// source-sha256: {digest}\n// nvrtc: {version}; options: {' '.join(OPTIONS)}\n")


def committed_hash():
    try:
        with open(PTX) as f:
            for line in f:
                m = re.match(r"// source-sha256: ([0-9a-f]{64})", line)
                if m:
                    return m.group(1)
    except FileNotFoundError:
        return None
    return None


def canonical_registers(ptx):
    """The PTX with each function's virtual registers renumbered in order of first use (per register class): two
    compilations that differ only in how NVRTC numbered the registers read the same."""
    out, names = [], {}
    token = re.compile(r"%([a-z]+)(\d+)\b")
    def rename(m):
        cls = m.group(1)
        key = (cls, m.group(2))
        if key not in names:
            names[key] = sum(1 for k in names if k[0] == cls)
        return f"%{cls}{names[key]}"
    for line in ptx.splitlines():
        if re.match(r"\s*(\.visible\s+|\.weak\s+)?(\.entry|\.func)\b", line):
            names = {}
        out.append(token.sub(rename, line))
    return "\n".join(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--write", action="store_true", help="rewrite the committed src/gpu/kernels/trace.ptx")
    ap.add_argument("--arch", default="sm_90", help="real architecture for ptxas (default sm_90)")
    args = ap.parse_args()
    nvrtc, ptxas = find_nvrtc(), find_ptxas()
    if nvrtc is None or ptxas is None:
        missing = " and ".join(n for n, v in [("NVRTC (pip nvidia-cuda-nvrtc)", nvrtc), ("ptxas (pip nvidia-cuda-nvcc)", ptxas)] if v is None)
        print(f"SKIP build_ptx: {missing} not found (scripts/setup.sh installs them into .venv unless DIFFCASSI_TORCH=skip)")
        return 0
    digest = source_hash()
    ptx, version = nvrtc_compile(nvrtc)
    # The one-file form the launcher falls back to (a driver older than this NVRTC) must give the same PTX.
    one_file, _ = nvrtc_compile(nvrtc, amalgamated())
    if one_file == ptx:
        print("build_ptx: the amalgamated kernel source (the launcher's NVRTC/nvcc fallback) compiles to the same PTX")
    elif canonical_registers(one_file) == canonical_registers(ptx):
        # NVRTC 13.0 numbers the virtual registers of the one-file source differently from one compilation to
        # the next (measured: 2 of 4 compilations in one process, e.g. %rd29 ↔ %rd30 in one function); the
        # instructions, operands and order are the same, which is what the fallback needs.
        print("build_ptx: the amalgamated kernel source (the launcher's NVRTC/nvcc fallback) compiles to the same PTX "
              "up to NVRTC's numbering of virtual registers")
    else:
        sys.exit("build_ptx: the amalgamated kernel source (the launcher's fallback) compiles to another PTX than device.cu")
    text = header(digest, version) + ptx
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "trace.ptx")
        with open(path, "w") as f:
            f.write(text)
        out = subprocess.run([ptxas, f"-arch={args.arch}", "-v", "--warn-on-spills", path, "-o", os.path.join(tmp, "trace.cubin")],
                             capture_output=True, text=True)
        report = (out.stdout + out.stderr).strip()
        if out.returncode != 0:
            sys.exit(f"build_ptx: ptxas -arch={args.arch} failed:\n{report}")
    print(f"build_ptx: NVRTC {version} ({nvrtc}) → PTX {ARCH}; ptxas -arch={args.arch} ({ptxas}):")
    for line in report.splitlines():
        print("  " + line)
    spills = re.findall(r"(\d+) bytes spill stores, (\d+) bytes spill loads", report)
    regs = re.findall(r"Used (\d+) registers", report)
    print(f"build_ptx: registers per thread {','.join(regs) or '?'}; spill stores/loads {' '.join('/'.join(s) for s in spills) or '0/0'} bytes")
    if args.write:
        with open(PTX, "w") as f:
            f.write(text)
        print(f"build_ptx: wrote {os.path.relpath(PTX, ROOT)} (source-sha256 {digest[:12]}…)")
    elif committed_hash() != digest:
        sys.exit(f"build_ptx: {os.path.relpath(PTX, ROOT)} is stale (built from other kernel sources): run python scripts/gpu/build_ptx.py --write and commit it")
    return 0


if __name__ == "__main__":
    sys.exit(main())
