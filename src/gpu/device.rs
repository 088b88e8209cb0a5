//! Finding a CUDA device: the driver library is opened at run time (nothing CUDA is needed to build or to run
//! on the CPU), and every failure is one message that says what is missing — no driver library, a driver
//! that fails to initialise, no device — never a panic (a plain `dlopen`, then `cuInit` and
//! `cuDeviceGetCount`; cudarc's `CudaContext::new` panics when libcuda.so is absent, so the probe comes first).
//! Devices are named as torch and the command line name them: `cuda` is device 0, `cuda:N` device N of the
//! devices the driver shows (after `CUDA_VISIBLE_DEVICES`); asking for one it lacks names how many it has.
use std::ffi::{c_char, c_int, c_void, CStr};

/// Device ordinals accepted (`cuda:0` … `cuda:63`): a launcher each, started on first use.
pub const MAX_DEVICES: usize = 64;

/// What the probe found.
#[derive(Clone, Debug, PartialEq)]
pub struct CudaInfo {
    /// Devices the driver reports.
    pub devices: usize,
    /// The device probed (its ordinal: `cuda:N`).
    pub ordinal: usize,
    /// That device's name (`cuDeviceGetName`).
    pub name: String,
    /// The driver's CUDA version, e.g. 13020 for 13.2 (`cuDriverGetVersion`).
    pub driver_version: i32,
}

/// Why no CUDA device can be used; the message names what is missing. Callers put the option or argument
/// in front (`--device cuda: …`, `device="cuda": …`) and what to use instead after it.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum DeviceError {
    #[error("no NVIDIA driver on this machine (the driver library could not be loaded: {0})")]
    NoDriver(String),
    #[error("the NVIDIA driver is installed but {0}")]
    Driver(String),
    #[error("the NVIDIA driver reports no CUDA device")]
    NoDevice,
    #[error("the NVIDIA driver reports {devices} CUDA device(s) (cuda:0 … cuda:{last}), not cuda:{ordinal}", last = .devices - 1)]
    NoSuchDevice { ordinal: usize, devices: usize },
    #[error("a CUDA device was found but the kernels could not be started on it: {0}")]
    Launcher(String),
}

/// The driver library's file names, most specific first.
const DRIVER_NAMES: [&str; 2] = ["libcuda.so.1", "libcuda.so"];

/// Every driver function the launcher ([`super::cuda`]) calls through cudarc, by the name cudarc 0.19 looks
/// up for its `cuda-13000` bindings (its `driver::result`: `cuMemAlloc_v2`, `cuEventElapsedTime_v2`, …). cudarc
/// looks each up when it is first called and panics when it is missing (`Missing symbol
/// cuDevicePrimaryCtxRetain`, a backtrace and exit 101 on a partial driver library; a held-out battery, round
/// 15): [`probe`] checks them all first, so such a library is one clear error.
pub const LAUNCHER_SYMBOLS: [&CStr; 20] = [
    c"cuInit",
    c"cuDeviceGet",
    c"cuDevicePrimaryCtxRetain",
    c"cuCtxSetCurrent",
    c"cuCtxSynchronize",
    c"cuModuleLoadData",
    c"cuModuleGetFunction",
    c"cuMemAlloc_v2",
    c"cuMemFree_v2",
    c"cuMemsetD8_v2",
    c"cuMemsetD8Async",
    c"cuMemcpyHtoD_v2",
    c"cuMemcpyDtoH_v2",
    c"cuMemGetInfo_v2",
    c"cuLaunchKernel",
    c"cuEventCreate",
    c"cuEventRecord",
    c"cuEventSynchronize",
    c"cuEventElapsedTime_v2",
    c"cuEventDestroy_v2",
];

fn dlerror_text() -> String {
    // SAFETY: dlerror returns a thread-local C string or null.
    unsafe {
        let e = libc::dlerror();
        if e.is_null() {
            "unknown error".into()
        } else {
            CStr::from_ptr(e).to_string_lossy().into_owned()
        }
    }
}

/// Probe the CUDA driver for device `ordinal` (0 for `cuda`): library, initialisation, device count, that
/// device's name and the driver version. Environment `DIFFCASSI_CUDA_DRIVER` names another driver library
/// (tests use a missing path, or the emulator of `tests/cuda_emu`).
pub fn probe(ordinal: usize) -> Result<CudaInfo, DeviceError> {
    let names: Vec<String> = match std::env::var("DIFFCASSI_CUDA_DRIVER") {
        Ok(p) if !p.is_empty() => vec![p],
        _ => DRIVER_NAMES.iter().map(|s| s.to_string()).collect(),
    };
    let mut handle: *mut c_void = std::ptr::null_mut();
    // Every name tried, each with its reason (the last alone named `libcuda.so` after `libcuda.so.1` was tried first).
    let mut why: Vec<String> = Vec::new();
    for name in &names {
        let c = std::ffi::CString::new(name.as_str()).map_err(|_| DeviceError::NoDriver(format!("bad library name {name:?}")))?;
        // SAFETY: dlopen with a valid C string; the handle is checked for null.
        handle = unsafe { libc::dlopen(c.as_ptr(), libc::RTLD_NOW | libc::RTLD_LOCAL) };
        if !handle.is_null() {
            break;
        }
        why.push(dlerror_text());
    }
    if handle.is_null() {
        return Err(DeviceError::NoDriver(why.join("; ")));
    }
    let sym = |name: &CStr| -> Result<*mut c_void, DeviceError> {
        // SAFETY: dlsym on a live handle with a valid C string.
        let p = unsafe { libc::dlsym(handle, name.as_ptr()) };
        if p.is_null() {
            Err(DeviceError::Driver(format!("its library lacks {}", name.to_string_lossy())))
        } else {
            Ok(p)
        }
    };
    type Init = unsafe extern "C" fn(u32) -> c_int;
    type Count = unsafe extern "C" fn(*mut c_int) -> c_int;
    type Get = unsafe extern "C" fn(*mut c_int, c_int) -> c_int;
    type Name = unsafe extern "C" fn(*mut c_char, c_int, c_int) -> c_int;
    type Version = unsafe extern "C" fn(*mut c_int) -> c_int;
    // SAFETY: the symbols are the CUDA driver API's, with these C signatures (cuda.h).
    unsafe {
        let init: Init = std::mem::transmute(sym(c"cuInit")?);
        let count: Count = std::mem::transmute(sym(c"cuDeviceGetCount")?);
        let get: Get = std::mem::transmute(sym(c"cuDeviceGet")?);
        let name: Name = std::mem::transmute(sym(c"cuDeviceGetName")?);
        let version: Version = std::mem::transmute(sym(c"cuDriverGetVersion")?);
        for f in LAUNCHER_SYMBOLS {
            sym(f)?;
        }
        let rc = init(0);
        if rc != 0 {
            return Err(DeviceError::Driver(format!("cuInit failed with CUDA error {rc}")));
        }
        let mut n: c_int = 0;
        if count(&mut n) != 0 || n <= 0 {
            return Err(DeviceError::NoDevice);
        }
        if ordinal >= n as usize {
            return Err(DeviceError::NoSuchDevice { ordinal, devices: n as usize });
        }
        let mut dev: c_int = 0;
        let mut buf = [0 as c_char; 256];
        let dev_name = if get(&mut dev, ordinal as c_int) == 0 && name(buf.as_mut_ptr(), buf.len() as c_int, dev) == 0 {
            CStr::from_ptr(buf.as_ptr()).to_string_lossy().into_owned()
        } else {
            "unknown device".into()
        };
        let mut v: c_int = 0;
        version(&mut v);
        Ok(CudaInfo { devices: n as usize, ordinal, name: dev_name, driver_version: v })
    }
}

/// What `--device cuda[:N]` checks before anything is written: the driver, device `ordinal`, and the
/// kernels loaded on it ([`super::cuda`]'s launcher, started once per process and device).
pub fn require_cuda(ordinal: usize) -> Result<CudaInfo, DeviceError> {
    probe(ordinal)?;
    super::cuda::device_info(ordinal).map(|(info, _)| info).map_err(|e| DeviceError::Launcher(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_driver_is_one_clear_error() {
        // Not via the environment (tests run in parallel): the same path the probe takes with a bad name.
        let c = std::ffi::CString::new("/nonexistent/libcuda.so.1").unwrap();
        let h = unsafe { libc::dlopen(c.as_ptr(), libc::RTLD_NOW) };
        assert!(h.is_null());
        let e = DeviceError::NoDriver(dlerror_text());
        let msg = e.to_string();
        assert!(msg.contains("no NVIDIA driver") && msg.contains("/nonexistent/libcuda.so.1"), "{msg}");
    }

    #[test]
    fn require_cuda_agrees_with_the_probe() {
        // Without a driver (CI) both fail alike; with one, require_cuda also loads the kernels.
        if probe(0).is_err() {
            assert_eq!(require_cuda(0).unwrap_err(), probe(0).unwrap_err());
        }
    }

    #[test]
    fn a_missing_ordinal_names_the_devices_there_are() {
        let msg = DeviceError::NoSuchDevice { ordinal: 3, devices: 2 }.to_string();
        assert_eq!(msg, "the NVIDIA driver reports 2 CUDA device(s) (cuda:0 … cuda:1), not cuda:3");
    }
}
