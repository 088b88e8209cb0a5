/* A CUDA driver emulator for the tests: a `libcuda.so.1` that runs the device build's entry points
 * (src/gpu/kernels/device.cu, compiled here for the host) so that the launcher of src/gpu/cuda.rs — cudarc's
 * driver calls, the uploads, the launch grids, the kernels' parameters, the copies back, the PTX fallbacks and
 * the errors — runs end to end on a machine without a GPU.
 *
 * What it checks, and what it cannot:
 *  - the PTX the launcher loads is read for what a driver reads before running it: `.version` (refused above
 *    CUDA_EMU_PTX_ISA, as an older driver refuses newer PTX: CUDA_ERROR_UNSUPPORTED_PTX_VERSION), `.target`
 *    (above sm_90, the H200's, refused: CUDA_ERROR_NO_BINARY_FOR_GPU), its `.entry` names (cuModuleGetFunction
 *    of a kernel the PTX lacks: CUDA_ERROR_NOT_FOUND) and each entry's parameter sizes, which must equal the
 *    host build's (sizeof of each parameter of the same function here): so NVRTC's struct layouts, the host
 *    compiler's and, through the launches, the Rust side's agree;
 *  - device memory is host memory, but every copy and memset must lie inside one live allocation of the current
 *    context's device, and every call needs cuInit and a current context on the calling thread
 *    (CUDA_ERROR_INVALID_CONTEXT otherwise), as a real driver requires; with CUDA_EMU_DEVICES > 1 each device has
 *    its own primary context, memory count and name, and a module, function or allocation of one device used
 *    while another's context is current is refused (what `--device cuda:N` must never do);
 *  - a launch runs the entry point's body (the same source as the PTX, device branch: atomics, shared memory,
 *    __syncthreads) block by block, each block's threads as fibers where the kernel synchronises, synchronously
 *    and in block order; grids and blocks beyond the hardware's limits are refused.
 *  - It says nothing about the device's numbers (the device's libdevice `tan`, its own code generation) or its
 *    speed: those are the GPU check's (scripts/gpu_check.sh). Its device name says it is an emulator, so that
 *    no record it writes passes for a GPU's.
 *
 * Environment: CUDA_EMU_PTX_ISA (e.g. "9.0": the newest PTX ISA the emulated driver takes; default any),
 * CUDA_EMU_REFUSE_PTX (refuse, as an unsupported PTX version, an image that holds this text: e.g. the embedded
 * PTX's header line, so that a fallback's PTX is the one loaded), CUDA_EMU_DRIVER_VERSION (default 13020), CUDA_EMU_DEVICES (default 1), CUDA_EMU_UNAVAILABLE (ordinals whose
 * context cannot be had, e.g. "0"), CUDA_EMU_INIT_ERROR (cuInit's result, default 0), CUDA_EMU_FREE_BYTES (cuMemGetInfo's free memory, default 8 GiB).
 * Built by tests/cuda_emu/build.sh (g++, -ffp-contract=off as the host twin); used by tests/gpu_launcher.rs and
 * tests/python/test_gpu_emulated.py through LD_LIBRARY_PATH.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>
#include <ucontext.h>

#include <map>
#include <mutex>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

/* ---- The CUDA built-ins device.cu uses, on the host ---------------------------------------------------- */
struct emu_dim3 {
    unsigned x, y, z;
};
static emu_dim3 emu_block_idx, emu_thread_idx, emu_block_dim, emu_grid_dim;
#define blockIdx emu_block_idx
#define threadIdx emu_thread_idx
#define blockDim emu_block_dim
#define gridDim emu_grid_dim
#define __global__
#define __device__
#define __host__
#define __forceinline__ inline
/* Blocks run one after another, so a block's shared memory can be one static array (each kernel sets it). */
#define __shared__ static
static inline double __longlong_as_double(long long v) {
    double d;
    memcpy(&d, &v, sizeof d);
    return d;
}
/* Launches run on one host thread at a time: the atomics are plain read-modify-writes. */
static inline unsigned long long atomicAdd(unsigned long long *p, unsigned long long v) {
    unsigned long long old = *p;
    *p = old + v;
    return old;
}
static inline unsigned long long atomicMin(unsigned long long *p, unsigned long long v) {
    unsigned long long old = *p;
    if (v < old) *p = v;
    return old;
}
static void __syncthreads();

/* The device branch of the kernel headers (dc_common.h: DC_DEVICE 1, atomics), as NVRTC compiles it. */
#define __CUDACC_RTC__ 1
#include "device.cu"
#undef __CUDACC_RTC__

/* ---- Fibers: a block's threads, for the kernels that synchronise ---------------------------------------- */
enum { FIBER_READY, FIBER_AT_BARRIER, FIBER_DONE };
struct Fiber {
    ucontext_t ctx;
    int state;
};
static ucontext_t g_scheduler;
static std::vector<Fiber> g_fibers;
static char *g_stacks = nullptr;
static size_t g_stack_count = 0;
static const size_t STACK_BYTES = 512 * 1024;
static unsigned g_current = 0;
static bool g_in_fiber = false;
static void (*g_body)(void **) = nullptr;
static void **g_params = nullptr;

static void __syncthreads() {
    if (!g_in_fiber) {
        /* A kernel that synchronises but is not marked so below: a bug of this file, said loudly. */
        fprintf(stderr, "cuda emulator: __syncthreads in a kernel not run as fibers\n");
        abort();
    }
    g_fibers[g_current].state = FIBER_AT_BARRIER;
    swapcontext(&g_fibers[g_current].ctx, &g_scheduler);
}

static void fiber_entry() {
    g_body(g_params);
    g_fibers[g_current].state = FIBER_DONE;
    /* returns to uc_link, the scheduler */
}

static bool ensure_stacks(size_t n) {
    if (n <= g_stack_count) return true;
    if (g_stacks) munmap(g_stacks, g_stack_count * STACK_BYTES);
    void *p = mmap(nullptr, n * STACK_BYTES, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (p == MAP_FAILED) {
        g_stacks = nullptr;
        g_stack_count = 0;
        return false;
    }
    g_stacks = (char *)p;
    g_stack_count = n;
    return true;
}

/* One block of a synchronising kernel: its threads as fibers, released together at each barrier. */
static bool run_block_fibers(unsigned n) {
    g_fibers.assign(n, Fiber());
    for (unsigned t = 0; t < n; ++t) {
        Fiber &f = g_fibers[t];
        getcontext(&f.ctx);
        f.ctx.uc_stack.ss_sp = g_stacks + (size_t)t * STACK_BYTES;
        f.ctx.uc_stack.ss_size = STACK_BYTES;
        f.ctx.uc_link = &g_scheduler;
        makecontext(&f.ctx, fiber_entry, 0);
        f.state = FIBER_READY;
    }
    for (;;) {
        for (unsigned t = 0; t < n; ++t) {
            if (g_fibers[t].state != FIBER_READY) continue;
            g_current = t;
            emu_thread_idx.x = t;
            g_in_fiber = true;
            swapcontext(&g_scheduler, &g_fibers[t].ctx);
            g_in_fiber = false;
        }
        unsigned waiting = 0, done = 0;
        for (unsigned t = 0; t < n; ++t) {
            waiting += g_fibers[t].state == FIBER_AT_BARRIER;
            done += g_fibers[t].state == FIBER_DONE;
        }
        if (done == n) return true;
        if (done > 0) return false; /* some threads left while others wait at a barrier: undefined in CUDA */
        for (unsigned t = 0; t < n; ++t) g_fibers[t].state = FIBER_READY;
    }
}

/* ---- The kernels: names, parameter sizes, bodies ------------------------------------------------------- */
template <typename... A, size_t... I>
static void invoke(void (*f)(A...), void **p, std::index_sequence<I...>) {
    f(*static_cast<std::remove_reference_t<A> *>(p[I])...);
}

struct Kernel {
    const char *name;
    std::vector<size_t> param_sizes;
    void (*body)(void **);
    bool synchronises;
};

template <typename... A>
static std::vector<size_t> sizes_of(void (*)(A...)) {
    return {sizeof(std::remove_reference_t<A>)...};
}

template <typename... A>
static constexpr size_t arity(void (*)(A...)) {
    return sizeof...(A);
}

#define EMU_BODY(fn) [](void **p) { invoke(fn, p, std::make_index_sequence<arity(fn)>{}); }

static const std::vector<Kernel> &kernels() {
    static const std::vector<Kernel> k = {
        {"dc_trace_kernel", sizes_of(dc_trace_kernel), EMU_BODY(dc_trace_kernel), false},
        {"dc_trace_f32_kernel", sizes_of(dc_trace_f32_kernel), EMU_BODY(dc_trace_f32_kernel), false},
        {"dc_landing_kernel", sizes_of(dc_landing_kernel), EMU_BODY(dc_landing_kernel), false},
        {"dc_landing_f32_kernel", sizes_of(dc_landing_f32_kernel), EMU_BODY(dc_landing_f32_kernel), false},
        {"dc_landing_aimed_kernel", sizes_of(dc_landing_aimed_kernel), EMU_BODY(dc_landing_aimed_kernel), false},
        {"dc_landing_aimed_f32_kernel", sizes_of(dc_landing_aimed_f32_kernel), EMU_BODY(dc_landing_aimed_f32_kernel), false},
        {"dc_footprint_size_kernel", sizes_of(dc_footprint_size_kernel), EMU_BODY(dc_footprint_size_kernel), false},
        {"dc_footprint_fill_kernel", sizes_of(dc_footprint_fill_kernel), EMU_BODY(dc_footprint_fill_kernel), false},
        {"dc_deposit_kernel", sizes_of(dc_deposit_kernel), EMU_BODY(dc_deposit_kernel), true},
        {"dc_deposit_aimed_kernel", sizes_of(dc_deposit_aimed_kernel), EMU_BODY(dc_deposit_aimed_kernel), true},
        {"dc_airy_kernel", sizes_of(dc_airy_kernel), EMU_BODY(dc_airy_kernel), false},
        {"dc_finish_kernel", sizes_of(dc_finish_kernel), EMU_BODY(dc_finish_kernel), false},
    };
    return k;
}

/* ---- The driver API subset the launcher calls (cuda.h's types and codes) ------------------------------- */
typedef int CUresult;
typedef int CUdevice;
typedef unsigned long long CUdeviceptr;
typedef void *CUcontext;
typedef void *CUstream;
struct EmuModule {
    std::map<std::string, std::vector<size_t>> entries; /* entry name → its .param sizes, from the PTX */
    int device;                                          /* the device whose context loaded it */
};
struct EmuFunction {
    const Kernel *kernel;
    int device;
};
struct EmuEvent {
    double ms;
    bool recorded;
};
typedef EmuModule *CUmodule;
typedef EmuFunction *CUfunction;
typedef EmuEvent *CUevent;

enum {
    CUDA_SUCCESS = 0,
    CUDA_ERROR_INVALID_VALUE = 1,
    CUDA_ERROR_OUT_OF_MEMORY = 2,
    CUDA_ERROR_NOT_INITIALIZED = 3,
    CUDA_ERROR_DEVICE_UNAVAILABLE = 46,
    CUDA_ERROR_NO_DEVICE = 100,
    CUDA_ERROR_INVALID_DEVICE = 101,
    CUDA_ERROR_INVALID_IMAGE = 200,
    CUDA_ERROR_INVALID_CONTEXT = 201,
    CUDA_ERROR_NO_BINARY_FOR_GPU = 209,
    CUDA_ERROR_INVALID_PTX = 218,
    CUDA_ERROR_UNSUPPORTED_PTX_VERSION = 222,
    CUDA_ERROR_INVALID_HANDLE = 400,
    CUDA_ERROR_NOT_FOUND = 500,
    CUDA_ERROR_LAUNCH_OUT_OF_RESOURCES = 701,
    CUDA_ERROR_LAUNCH_FAILED = 719,
    CUDA_ERROR_NOT_SUPPORTED = 801,
};

#define EMU_API extern "C" __attribute__((visibility("default")))

static std::mutex g_lock;
static bool g_initialised = false;
/* Device d's primary context is &g_contexts[d] (the emulator's devices: CUDA_EMU_DEVICES ≤ 64). */
static const int MAX_EMU_DEVICES = 64;
static int g_contexts[MAX_EMU_DEVICES];
static thread_local CUcontext t_current = nullptr;
struct EmuAllocation {
    size_t bytes;
    int device;
};
static std::map<CUdeviceptr, EmuAllocation> g_allocations;
static size_t g_allocated[MAX_EMU_DEVICES];

static long env_long(const char *name, long fallback) {
    const char *v = getenv(name);
    return v && *v ? strtol(v, nullptr, 10) : fallback;
}

static int device_count() {
    long n = env_long("CUDA_EMU_DEVICES", 1);
    return n < 0 ? 0 : n > MAX_EMU_DEVICES ? MAX_EMU_DEVICES : (int)n;
}

/* The current context's device (a context is current: ready() was checked). */
static int current_device() { return (int)((int *)t_current - g_contexts); }

static size_t total_bytes() {
    const char *v = getenv("CUDA_EMU_FREE_BYTES");
    return v && *v ? (size_t)strtoull(v, nullptr, 10) : ((size_t)8 << 30);
}

static size_t free_bytes() {
    size_t used = g_allocated[current_device()];
    return total_bytes() > used ? total_bytes() - used : 0;
}

static CUresult ready() {
    if (!g_initialised) return CUDA_ERROR_NOT_INITIALIZED;
    if (t_current == nullptr) return CUDA_ERROR_INVALID_CONTEXT;
    return CUDA_SUCCESS;
}

/* [p, p + n) inside one live allocation of the current context's device. */
static bool inside(CUdeviceptr p, size_t n) {
    auto it = g_allocations.upper_bound(p);
    if (it == g_allocations.begin()) return false;
    --it;
    return p >= it->first && p + n <= it->first + it->second.bytes && it->second.device == current_device();
}

static double now_ms() {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

EMU_API CUresult cuInit(unsigned int flags) {
    std::lock_guard<std::mutex> g(g_lock);
    if (flags != 0) return CUDA_ERROR_INVALID_VALUE;
    long e = env_long("CUDA_EMU_INIT_ERROR", 0);
    if (e != 0) return (CUresult)e;
    g_initialised = true;
    return CUDA_SUCCESS;
}

EMU_API CUresult cuDriverGetVersion(int *v) {
    if (!v) return CUDA_ERROR_INVALID_VALUE;
    *v = (int)env_long("CUDA_EMU_DRIVER_VERSION", 13020);
    return CUDA_SUCCESS;
}

EMU_API CUresult cuDeviceGetCount(int *n) {
    if (!g_initialised) return CUDA_ERROR_NOT_INITIALIZED;
    if (!n) return CUDA_ERROR_INVALID_VALUE;
    *n = device_count();
    return CUDA_SUCCESS;
}

EMU_API CUresult cuDeviceGet(CUdevice *d, int ordinal) {
    if (!g_initialised) return CUDA_ERROR_NOT_INITIALIZED;
    if (!d) return CUDA_ERROR_INVALID_VALUE;
    if (ordinal < 0 || ordinal >= device_count()) return CUDA_ERROR_INVALID_DEVICE;
    *d = ordinal;
    return CUDA_SUCCESS;
}

EMU_API CUresult cuDeviceGetName(char *name, int len, CUdevice d) {
    if (!g_initialised) return CUDA_ERROR_NOT_INITIALIZED;
    if (!name || len <= 0) return CUDA_ERROR_INVALID_VALUE;
    if (d < 0 || d >= device_count()) return CUDA_ERROR_INVALID_DEVICE;
    if (d == 0)
        snprintf(name, (size_t)len, "%s", "diffcassi CUDA emulator (host, not a GPU)");
    else
        snprintf(name, (size_t)len, "diffcassi CUDA emulator, device %d (host, not a GPU)", d);
    return CUDA_SUCCESS;
}

EMU_API CUresult cuDevicePrimaryCtxRetain(CUcontext *ctx, CUdevice d) {
    if (!g_initialised) return CUDA_ERROR_NOT_INITIALIZED;
    if (!ctx) return CUDA_ERROR_INVALID_VALUE;
    if (d < 0 || d >= device_count()) return CUDA_ERROR_INVALID_DEVICE;
    /* CUDA_EMU_UNAVAILABLE: devices (a comma-separated list of ordinals) held by another process, as a GPU in
     * exclusive-process mode is: their context cannot be had. */
    const char *busy = getenv("CUDA_EMU_UNAVAILABLE");
    for (const char *at = busy; at && *at;) {
        char *end = nullptr;
        long b = strtol(at, &end, 10);
        if (end == at) break;
        if (b == d) return CUDA_ERROR_DEVICE_UNAVAILABLE;
        at = *end == ',' ? end + 1 : end;
    }
    *ctx = &g_contexts[d];
    return CUDA_SUCCESS;
}

EMU_API CUresult cuDevicePrimaryCtxRelease_v2(CUdevice d) { return d >= 0 && d < device_count() ? CUDA_SUCCESS : CUDA_ERROR_INVALID_DEVICE; }

EMU_API CUresult cuCtxSetCurrent(CUcontext ctx) {
    if (!g_initialised) return CUDA_ERROR_NOT_INITIALIZED;
    if (ctx != nullptr && !((int *)ctx >= g_contexts && (int *)ctx < g_contexts + device_count())) return CUDA_ERROR_INVALID_CONTEXT;
    t_current = ctx;
    return CUDA_SUCCESS;
}

EMU_API CUresult cuCtxGetCurrent(CUcontext *ctx) {
    if (!g_initialised) return CUDA_ERROR_NOT_INITIALIZED;
    if (!ctx) return CUDA_ERROR_INVALID_VALUE;
    *ctx = t_current;
    return CUDA_SUCCESS;
}

EMU_API CUresult cuCtxSynchronize() { return ready(); }
EMU_API CUresult cuStreamSynchronize(CUstream) { return ready(); }

/* The PTX's ISA version as major·10 + minor ("9.2" → 92), −1 if absent. */
static int ptx_isa(const std::string &ptx) {
    size_t at = ptx.find("\n.version ");
    if (at == std::string::npos) return -1;
    int major = 0, minor = 0;
    if (sscanf(ptx.c_str() + at + 10, "%d.%d", &major, &minor) != 2) return -1;
    return major * 10 + minor;
}

static size_t param_size(const std::string &decl) {
    /* ".param .align 8 .b8 NAME[152]" or ".param .u64 NAME" */
    size_t lb = decl.find('[');
    if (lb != std::string::npos) return (size_t)strtoull(decl.c_str() + lb + 1, nullptr, 10);
    static const char *eight[] = {".u64", ".s64", ".b64", ".f64"};
    static const char *four[] = {".u32", ".s32", ".b32", ".f32"};
    for (const char *t : eight)
        if (decl.find(t) != std::string::npos) return 8;
    for (const char *t : four)
        if (decl.find(t) != std::string::npos) return 4;
    return 0;
}

EMU_API CUresult cuModuleLoadData(CUmodule *module, const void *image) {
    std::lock_guard<std::mutex> g(g_lock);
    CUresult r = ready();
    if (r) return r;
    if (!module || !image) return CUDA_ERROR_INVALID_VALUE;
    std::string ptx((const char *)image);
    int isa = ptx_isa(ptx);
    if (isa < 0 || ptx.find("\n.address_size 64") == std::string::npos) return CUDA_ERROR_INVALID_PTX;
    const char *max_isa = getenv("CUDA_EMU_PTX_ISA");
    if (max_isa && *max_isa) {
        int major = 0, minor = 0;
        sscanf(max_isa, "%d.%d", &major, &minor);
        if (isa > major * 10 + minor) return CUDA_ERROR_UNSUPPORTED_PTX_VERSION;
    }
    const char *refuse = getenv("CUDA_EMU_REFUSE_PTX");
    if (refuse && *refuse && ptx.find(refuse) != std::string::npos) return CUDA_ERROR_UNSUPPORTED_PTX_VERSION;
    size_t t = ptx.find("\n.target sm_");
    if (t == std::string::npos || atoi(ptx.c_str() + t + 12) > 90) return CUDA_ERROR_NO_BINARY_FOR_GPU;
    EmuModule *m = new EmuModule();
    m->device = current_device();
    for (size_t at = ptx.find(".entry "); at != std::string::npos; at = ptx.find(".entry ", at + 7)) {
        size_t open = ptx.find('(', at), close = ptx.find(')', at);
        if (open == std::string::npos || close == std::string::npos) break;
        std::string name = ptx.substr(at + 7, open - at - 7);
        std::vector<size_t> sizes;
        std::string params = ptx.substr(open + 1, close - open - 1);
        for (size_t p = params.find(".param"); p != std::string::npos; p = params.find(".param", p + 6)) {
            size_t end = params.find_first_of(",\n", p);
            sizes.push_back(param_size(params.substr(p, end == std::string::npos ? std::string::npos : end - p)));
        }
        m->entries[name] = sizes;
    }
    *module = m;
    return CUDA_SUCCESS;
}

EMU_API CUresult cuModuleUnload(CUmodule m) {
    delete m;
    return CUDA_SUCCESS;
}

EMU_API CUresult cuModuleGetFunction(CUfunction *f, CUmodule m, const char *name) {
    std::lock_guard<std::mutex> g(g_lock);
    CUresult r = ready();
    if (r) return r;
    if (!f || !m || !name) return CUDA_ERROR_INVALID_VALUE;
    if (m->device != current_device()) return CUDA_ERROR_INVALID_CONTEXT; /* another device's module */
    auto e = m->entries.find(name);
    if (e == m->entries.end()) return CUDA_ERROR_NOT_FOUND;
    for (const Kernel &k : kernels()) {
        if (strcmp(k.name, name) != 0) continue;
        if (e->second != k.param_sizes) {
            fprintf(stderr, "cuda emulator: the PTX's %s takes %zu parameters (", name, e->second.size());
            for (size_t s : e->second) fprintf(stderr, " %zu", s);
            fprintf(stderr, " bytes), the host build's %zu (", k.param_sizes.size());
            for (size_t s : k.param_sizes) fprintf(stderr, " %zu", s);
            fprintf(stderr, " bytes)\n");
            return CUDA_ERROR_INVALID_IMAGE;
        }
        *f = new EmuFunction{&k, m->device};
        return CUDA_SUCCESS;
    }
    return CUDA_ERROR_NOT_FOUND; /* in the PTX but not an entry point of device.cu: a stale PTX */
}

EMU_API CUresult cuMemGetInfo_v2(size_t *free_, size_t *total) {
    std::lock_guard<std::mutex> g(g_lock);
    CUresult r = ready();
    if (r) return r;
    if (!free_ || !total) return CUDA_ERROR_INVALID_VALUE;
    *total = total_bytes();
    *free_ = free_bytes();
    return CUDA_SUCCESS;
}

EMU_API CUresult cuMemAlloc_v2(CUdeviceptr *p, size_t bytes) {
    std::lock_guard<std::mutex> g(g_lock);
    CUresult r = ready();
    if (r) return r;
    if (!p || bytes == 0) return CUDA_ERROR_INVALID_VALUE;
    if (bytes > free_bytes()) return CUDA_ERROR_OUT_OF_MEMORY;
    void *m = aligned_alloc(256, (bytes + 255) / 256 * 256);
    if (!m) return CUDA_ERROR_OUT_OF_MEMORY;
    /* Fresh device memory is not zero: a launcher that reads before it writes shows it. */
    memset(m, 0xA5, bytes);
    *p = (CUdeviceptr)(uintptr_t)m;
    g_allocations[*p] = EmuAllocation{bytes, current_device()};
    g_allocated[current_device()] += bytes;
    return CUDA_SUCCESS;
}

EMU_API CUresult cuMemFree_v2(CUdeviceptr p) {
    std::lock_guard<std::mutex> g(g_lock);
    CUresult r = ready();
    if (r) return r;
    auto it = g_allocations.find(p);
    if (it == g_allocations.end() || it->second.device != current_device()) return CUDA_ERROR_INVALID_VALUE;
    g_allocated[it->second.device] -= it->second.bytes;
    g_allocations.erase(it);
    free((void *)(uintptr_t)p);
    return CUDA_SUCCESS;
}

EMU_API CUresult cuMemsetD8_v2(CUdeviceptr p, unsigned char v, size_t n) {
    std::lock_guard<std::mutex> g(g_lock);
    CUresult r = ready();
    if (r) return r;
    if (!inside(p, n)) return CUDA_ERROR_INVALID_VALUE;
    memset((void *)(uintptr_t)p, v, n);
    return CUDA_SUCCESS;
}

EMU_API CUresult cuMemsetD8Async(CUdeviceptr p, unsigned char v, size_t n, CUstream) { return cuMemsetD8_v2(p, v, n); }

EMU_API CUresult cuMemcpyHtoD_v2(CUdeviceptr dst, const void *src, size_t n) {
    std::lock_guard<std::mutex> g(g_lock);
    CUresult r = ready();
    if (r) return r;
    if (!src || !inside(dst, n)) return CUDA_ERROR_INVALID_VALUE;
    memcpy((void *)(uintptr_t)dst, src, n);
    return CUDA_SUCCESS;
}

EMU_API CUresult cuMemcpyDtoH_v2(void *dst, CUdeviceptr src, size_t n) {
    std::lock_guard<std::mutex> g(g_lock);
    CUresult r = ready();
    if (r) return r;
    if (!dst || !inside(src, n)) return CUDA_ERROR_INVALID_VALUE;
    memcpy(dst, (const void *)(uintptr_t)src, n);
    return CUDA_SUCCESS;
}

EMU_API CUresult cuLaunchKernel(CUfunction f, unsigned gx, unsigned gy, unsigned gz, unsigned bx, unsigned by, unsigned bz,
                                unsigned shared_bytes, CUstream stream, void **params, void **extra) {
    std::lock_guard<std::mutex> g(g_lock);
    CUresult r = ready();
    if (r) return r;
    if (!f || !f->kernel || f->device != current_device()) return CUDA_ERROR_INVALID_HANDLE; /* another device's kernel */
    if (stream != nullptr || extra != nullptr || (params == nullptr && !f->kernel->param_sizes.empty())) return CUDA_ERROR_INVALID_VALUE;
    /* sm_90's limits: 1024 threads a block, grid x < 2^31, y and z < 2^16; the kernels use no dynamic shared memory. */
    if (bx == 0 || by == 0 || bz == 0 || gx == 0 || gy == 0 || gz == 0) return CUDA_ERROR_INVALID_VALUE;
    if ((unsigned long long)bx * by * bz > 1024 || gx >= (1u << 31) || gy >= (1u << 16) || gz >= (1u << 16)) return CUDA_ERROR_INVALID_VALUE;
    if (shared_bytes != 0) return CUDA_ERROR_INVALID_VALUE;
    if (by != 1 || bz != 1 || gy != 1 || gz != 1) return CUDA_ERROR_INVALID_VALUE; /* the kernels index x only */
    const Kernel &k = *f->kernel;
    emu_block_dim = {bx, 1, 1};
    emu_grid_dim = {gx, 1, 1};
    emu_thread_idx = {0, 0, 0};
    if (k.synchronises) {
        if (!ensure_stacks(bx)) return CUDA_ERROR_LAUNCH_OUT_OF_RESOURCES;
        g_body = k.body;
        g_params = params;
        for (unsigned b = 0; b < gx; ++b) {
            emu_block_idx = {b, 0, 0};
            if (!run_block_fibers(bx)) {
                fprintf(stderr, "cuda emulator: %s: in block %u some threads ended while others waited at __syncthreads\n", k.name, b);
                return CUDA_ERROR_LAUNCH_FAILED;
            }
        }
    } else {
        for (unsigned b = 0; b < gx; ++b) {
            emu_block_idx = {b, 0, 0};
            for (unsigned t = 0; t < bx; ++t) {
                emu_thread_idx.x = t;
                k.body(params);
            }
        }
    }
    return CUDA_SUCCESS;
}

EMU_API CUresult cuEventCreate(CUevent *e, unsigned int) {
    CUresult r = ready();
    if (r) return r;
    if (!e) return CUDA_ERROR_INVALID_VALUE;
    *e = new EmuEvent{0.0, false};
    return CUDA_SUCCESS;
}

EMU_API CUresult cuEventRecord(CUevent e, CUstream) {
    CUresult r = ready();
    if (r) return r;
    if (!e) return CUDA_ERROR_INVALID_HANDLE;
    e->ms = now_ms();
    e->recorded = true;
    return CUDA_SUCCESS;
}

EMU_API CUresult cuEventSynchronize(CUevent e) {
    CUresult r = ready();
    if (r) return r;
    return e ? CUDA_SUCCESS : CUDA_ERROR_INVALID_HANDLE;
}

EMU_API CUresult cuEventElapsedTime_v2(float *ms, CUevent a, CUevent b) {
    CUresult r = ready();
    if (r) return r;
    if (!ms || !a || !b) return CUDA_ERROR_INVALID_VALUE;
    if (!a->recorded || !b->recorded) return CUDA_ERROR_INVALID_HANDLE;
    *ms = (float)(b->ms - a->ms);
    return CUDA_SUCCESS;
}

EMU_API CUresult cuEventElapsedTime(float *ms, CUevent a, CUevent b) { return cuEventElapsedTime_v2(ms, a, b); }

EMU_API CUresult cuEventDestroy_v2(CUevent e) {
    if (!e) return CUDA_ERROR_INVALID_HANDLE;
    delete e;
    return CUDA_SUCCESS;
}

/* The driver's private tables (NVRTC asks for them when a driver is loaded): none here. Without this entry point
 * NVRTC 13 crashes in a process that has an initialised libcuda.so.1 without it. */
EMU_API CUresult cuGetExportTable(const void **table, const void *) {
    if (table) *table = nullptr;
    return CUDA_ERROR_NOT_SUPPORTED;
}

static const char *error_name(CUresult r) {
    switch (r) {
    case CUDA_SUCCESS: return "CUDA_SUCCESS";
    case CUDA_ERROR_INVALID_VALUE: return "CUDA_ERROR_INVALID_VALUE";
    case CUDA_ERROR_OUT_OF_MEMORY: return "CUDA_ERROR_OUT_OF_MEMORY";
    case CUDA_ERROR_NOT_INITIALIZED: return "CUDA_ERROR_NOT_INITIALIZED";
    case CUDA_ERROR_DEVICE_UNAVAILABLE: return "CUDA_ERROR_DEVICE_UNAVAILABLE";
    case CUDA_ERROR_NO_DEVICE: return "CUDA_ERROR_NO_DEVICE";
    case CUDA_ERROR_INVALID_DEVICE: return "CUDA_ERROR_INVALID_DEVICE";
    case CUDA_ERROR_INVALID_IMAGE: return "CUDA_ERROR_INVALID_IMAGE";
    case CUDA_ERROR_INVALID_CONTEXT: return "CUDA_ERROR_INVALID_CONTEXT";
    case CUDA_ERROR_NO_BINARY_FOR_GPU: return "CUDA_ERROR_NO_BINARY_FOR_GPU";
    case CUDA_ERROR_INVALID_PTX: return "CUDA_ERROR_INVALID_PTX";
    case CUDA_ERROR_UNSUPPORTED_PTX_VERSION: return "CUDA_ERROR_UNSUPPORTED_PTX_VERSION";
    case CUDA_ERROR_INVALID_HANDLE: return "CUDA_ERROR_INVALID_HANDLE";
    case CUDA_ERROR_NOT_FOUND: return "CUDA_ERROR_NOT_FOUND";
    case CUDA_ERROR_LAUNCH_OUT_OF_RESOURCES: return "CUDA_ERROR_LAUNCH_OUT_OF_RESOURCES";
    case CUDA_ERROR_LAUNCH_FAILED: return "CUDA_ERROR_LAUNCH_FAILED";
    case CUDA_ERROR_NOT_SUPPORTED: return "CUDA_ERROR_NOT_SUPPORTED";
    default: return nullptr;
    }
}

EMU_API CUresult cuGetErrorName(CUresult r, const char **s) {
    if (!s) return CUDA_ERROR_INVALID_VALUE;
    *s = error_name(r);
    return *s ? CUDA_SUCCESS : CUDA_ERROR_INVALID_VALUE;
}

EMU_API CUresult cuGetErrorString(CUresult r, const char **s) { return cuGetErrorName(r, s); }
