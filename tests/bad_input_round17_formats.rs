//! Round 17 of the held-out battery, prober C (2 Dec 2026): the file formats the program reads. Each case
//! failed before its fix (docs/robustness.md, "round 17"): a multi-part EXR read up to its first part, EXR
//! channel names written by `make-scene` that read back as another wavelength, integer NPY cubes 3× over the
//! memory budget, the calibration cache read around the safe input reader, misleading messages.
use crate::cli_run::{ok_cli as ok, refused_cli as refused};
use diffcassi::io::exr::{read_exr, ExrChannel};
use diffcassi::scene::{band_channel_name, load_scene, save_exr, save_png_stack, wavelength_from_name};
use diffcassi::scene::SpectralCube;
use std::path::Path;

/// A two-part scanline EXR (the `exr` crate's writer): part `p1` holds `w450nm`, `w500nm`, part `p2`
/// `w600nm`, `w650nm`; `p2` is `w2 × h2` pixels.
fn write_two_parts(path: &Path, (w2, h2): (usize, usize), p2_names: [&str; 2]) {
    use exr::prelude::*;
    let layer = |name: &str, (w, h): (usize, usize), chans: [(&str, f32); 2]| {
        let list: SmallVec<[AnyChannel<FlatSamples>; 4]> = chans.iter().map(|(n, v)| AnyChannel::new(*n, FlatSamples::F32((0..w * h).map(|i| v + i as f32 * 1e-3).collect()))).collect();
        Layer::new((w, h), LayerAttributes::named(name), Encoding::UNCOMPRESSED, AnyChannels::sort(list))
    };
    let p1 = layer("p1", (12, 11), [("w450nm", 0.1), ("w500nm", 0.2)]);
    let p2 = layer("p2", (w2, h2), [(p2_names[0], 0.3), (p2_names[1], 0.4)]);
    let image = Image::from_layers(ImageAttributes::new(IntegerBounds::from_dimensions((12, 11))), vec![p1, p2]);
    image.write().non_parallel().to_file(path).unwrap();
}

/// Every part of a multi-part EXR is read (the second part's bands were dropped without a word: `evaluate`
/// compared 2 of 4 bands, rmse 0); parts of different sizes, or one band name in two parts, are refused
/// naming the parts.
#[test]
fn multi_part_exr_reads_every_part() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("multi.exr");
    write_two_parts(&p, (12, 11), ["w600nm", "w650nm"]);
    let img = read_exr(&p).unwrap();
    let names: Vec<&str> = img.channels.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["w450nm", "w500nm", "w600nm", "w650nm"]);
    assert_eq!(img.channels[3].data[5], 0.4 + 5.0 * 1e-3);
    let cube = load_scene(&p, None).unwrap();
    assert_eq!(cube.wavelengths_nm, vec![450.0, 500.0, 600.0, 650.0]);
    assert_eq!(cube.data[4 * 5 + 2], 0.3 + 5.0 * 1e-3); // pixel 5, band 2 (600 nm), from part p2

    let out = ok(dir.path(), &["evaluate", "--truth", "multi.exr", "--estimate", "multi.exr"]);
    assert!(out.contains("11×12×4 (450.0–650.0 nm)"), "{out}");

    write_two_parts(&p, (13, 11), ["w600nm", "w650nm"]);
    let e = read_exr(&p).unwrap_err().to_string();
    assert!(e.contains("multi.exr") && e.contains("part 1 `p2` is 13×11") && e.contains("part 0 `p1` is 12×11") && e.contains("one data window"), "{e}");
    write_two_parts(&p, (12, 11), ["w500nm", "w650nm"]);
    let e = read_exr(&p).unwrap_err().to_string();
    assert!(e.contains("channel `w500nm` is in both part 0 `p1` and part 1 `p2`"), "{e}");
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|w| w.to_bits()).collect()
}

fn cube_at(ws: Vec<f64>) -> SpectralCube {
    let n = 2 * 2 * ws.len();
    SpectralCube::new(2, 2, ws, (0..n).map(|i| (i % 7) as f32 * 0.125).collect(), "t").unwrap()
}

/// Every EXR the program writes reads back with the same wavelengths, bit for bit: wavelengths over the whole
/// window the program accepts (100–20 000 nm; only 200–3000 read back), and 201+ bands, whose zero-padded
/// index `band_200_…` was read as 200 nm.
#[test]
fn own_exr_and_png_names_read_back_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let ir = vec![2800.0, 3000.0, 3200.0];
    let uv = diffcassi::analysis::linspace(150.0, 190.0, 3);
    let edges = vec![100.0, 20_000.0];
    let many: Vec<f64> = (0..200).map(|k| 400.0 + k as f64).chain([3500.0]).collect();
    let odd: Vec<f64> = diffcassi::analysis::linspace(100.0, 20_000.0, 257);
    for (k, ws) in [ir, uv, edges, many, odd].into_iter().enumerate() {
        let cube = cube_at(ws.clone());
        let p = dir.path().join(format!("c{k}.exr"));
        save_exr(&cube, &p).unwrap();
        let back = load_scene(&p, None).unwrap();
        assert_eq!(bits(&back.wavelengths_nm), bits(&ws), "case {k}");
        assert_eq!(back.data, cube.data, "case {k}");
    }
    // A PNG stack's file names carry the same names.
    let cube = cube_at((0..201).map(|k| 400.0 + k as f64 * 0.5).collect::<Vec<_>>().into_iter().chain([3500.0]).collect());
    let stack = dir.path().join("stack");
    std::fs::create_dir(&stack).unwrap();
    save_png_stack(&cube, &stack).unwrap();
    assert_eq!(bits(&load_scene(&stack, None).unwrap().wavelengths_nm), bits(&cube.wavelengths_nm));

    assert_eq!(band_channel_name(200, 201, 3500.0), "band_200_3500nm");
    assert_eq!(wavelength_from_name("band_200_3500nm"), Some(3500.0));
    assert_eq!(wavelength_from_name("band_02_150nm"), Some(150.0));
    assert_eq!(wavelength_from_name("w450 NM"), Some(450.0));
    assert_eq!(wavelength_from_name("band_250_50nm"), None); // outside the window: never the index 250
    assert_eq!(wavelength_from_name("cave_450"), Some(450.0)); // no `nm` number: the old rule
    // A name whose `nm` number lies outside the window is an error saying so.
    let p = dir.path().join("far.exr");
    diffcassi::io::exr::write_exr(&p, 1, 1, &[ExrChannel { name: "band_250_50nm".into(), data: vec![0.5] }]).unwrap();
    let e = load_scene(&p, None).unwrap_err().to_string();
    assert!(e.contains("`band_250_50nm` names 50 nm, outside the 100–20000 nm"), "{e}");
}

/// An 8-bit NPY cube went through an `f64` vector (8 B per element) and peaked at ≈ 12× its file, 3× over
/// `--max-memory-gb`. It is now converted straight to `f32` and checked from the header's element count:
/// a 10 MB `|u1` cube needs the file + 4 B per element = 50 MB, refused under a 30 MB budget, read under 80 MB.
#[test]
fn integer_npy_cube_is_checked_from_its_element_count() {
    let dir = tempfile::tempdir().unwrap();
    let (h, w, b) = (1000usize, 1000usize, 10usize);
    let data: Vec<u8> = (0..h * w * b).map(|i| (i % 251) as u8).collect();
    diffcassi::io::write_npy_u8(dir.path().join("u8.npy"), &[h, w, b], &data).unwrap();
    let ws: Vec<f64> = diffcassi::analysis::linspace(450.0, 650.0, b);
    diffcassi::io::write_npy_f64(dir.path().join("u8_wavelengths_nm.npy"), &[b], &ws).unwrap();
    let args = |gb: &'static str| ["--max-memory-gb", gb, "evaluate", "--truth", "u8.npy", "--estimate", "u8.npy"];
    refused(dir.path(), &args("0.03"), &["u8.npy", "'|u1'", "4 bytes per element", "--max-memory-gb 0.03"]);
    let out = ok(dir.path(), &args("0.2"));
    assert!(out.contains("rmse"), "{out}");
    // Values read exactly (u8 as raw values, as documented).
    let (shape, v) = diffcassi::io::read_npy_f32(dir.path().join("u8.npy")).unwrap();
    assert_eq!(shape, vec![h, w, b]);
    assert_eq!((v[0], v[250], v[251], v[h * w * b - 1]), (0.0, 250.0, 0.0, ((h * w * b - 1) % 251) as f32));
}

/// The calibration cache went around the safe input reader: a FIFO in an entry's place hung the render, a
/// link to /dev/zero was read until memory ran out. Each is a corrupt entry now, at once.
#[test]
fn calibration_cache_entries_go_through_the_input_reader() {
    use diffcassi::fidelity::cache::{load, store, CacheKey, Lookup, MAX_ENTRY_BYTES};
    let dir = tempfile::tempdir().unwrap();
    let key = CacheKey::new("test", &["round17"]);
    let p = dir.path().join(key.file_name());
    let t = std::time::Instant::now();
    let c = std::ffi::CString::new(p.to_str().unwrap()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let why = |l: Lookup<Vec<f64>>| match l {
        Lookup::Corrupt(w) => w,
        Lookup::Hit(_) => panic!("hit"),
        Lookup::Miss => panic!("miss"),
    };
    let w = why(load(dir.path(), &key, |_| true));
    assert!(w.contains("named pipe"), "{w}");
    assert!(t.elapsed().as_secs() < 5);
    std::fs::remove_file(&p).unwrap();
    std::os::unix::fs::symlink("/dev/zero", &p).unwrap();
    let w = why(load(dir.path(), &key, |_| true));
    assert!(w.contains("character device"), "{w}");
    std::fs::remove_file(&p).unwrap();
    std::fs::File::create(&p).unwrap().set_len(MAX_ENTRY_BYTES + 1).unwrap();
    let w = why(load(dir.path(), &key, |_| true));
    assert!(w.contains("limit"), "{w}");
    // A dangling link is no entry; a good entry is still a hit.
    std::fs::remove_file(&p).unwrap();
    std::os::unix::fs::symlink(dir.path().join("gone"), &p).unwrap();
    assert!(matches!(load::<Vec<f64>>(dir.path(), &key, |_| true), Lookup::Miss));
    store(dir.path(), &key, &vec![1.5]).unwrap();
    assert!(matches!(load::<Vec<f64>>(dir.path(), &key, |_| true), Lookup::Hit(v) if v == vec![1.5]));
}

/// A finite float64 value beyond the float32 range was reported as "inf (not finite)"; `1e400` in a
/// wavelengths.txt as "wavelength 2 = inf nm" (and a `nan` at the index it had after sorting).
#[test]
fn values_beyond_float32_and_non_finite_wavelengths_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let mut v = vec![0.5f64; 3 * 3 * 3];
    v[2 * 9 + 2 * 3 + 2] = 1e39;
    diffcassi::io::write_npy_f64(dir.path().join("big.npy"), &[3, 3, 3], &v).unwrap();
    diffcassi::io::write_npy_f64(dir.path().join("big_wavelengths_nm.npy"), &[3], &[450.0, 550.0, 650.0]).unwrap();
    let e = load_scene(&dir.path().join("big.npy"), None).unwrap_err().to_string();
    assert!(e.contains("row 2, col 2, band 2 is 1e39") && e.contains("beyond the float32 range") && !e.contains("inf"), "{e}");

    let stack = dir.path().join("stack");
    std::fs::create_dir(&stack).unwrap();
    for k in 0..3 {
        diffcassi::io::png16::write_png_gray16(stack.join(format!("b{k}.png")), 2, 2, &[0, 1, 2, 3]).unwrap();
    }
    for (text, needle) in [("450 1e400 600", "wavelength 1 (`1e400`) is not a finite number"), ("450 nan 600", "wavelength 1 (`nan`) is not a finite number"), ("450 x 600", "wavelength 1: `x` is not a number")] {
        std::fs::write(stack.join("wavelengths.txt"), text).unwrap();
        let e = load_scene(&stack, None).unwrap_err().to_string();
        assert!(e.contains("wavelengths.txt") && e.contains(needle), "{text}: {e}");
    }
}

/// A UTF-8 byte-order mark was refused in `.json` ("expected value at line 1 column 1") and glued to the
/// first key in `.yml`; it is skipped as the TOML, CSV, `.zmx` and AGF readers skip it.
#[test]
fn byte_order_mark_is_skipped_in_json_and_yaml_specs() {
    let dir = tempfile::tempdir().unwrap();
    let json = diffcassi::spec::to_json(&diffcassi::presets::spec("sp").unwrap()).unwrap();
    std::fs::write(dir.path().join("bom.json"), format!("\u{feff}{json}")).unwrap();
    let spec = diffcassi::spec::load_spec_file(dir.path().join("bom.json")).unwrap();
    assert_eq!(spec.name, "sp");
    // YAML: the same outcome with and without the mark (here the same refusal of an incomplete file).
    let yaml = "device: cuda\n";
    std::fs::write(dir.path().join("a.yml"), yaml).unwrap();
    std::fs::write(dir.path().join("b.yml"), format!("\u{feff}{yaml}")).unwrap();
    let a = diffcassi::spec::load_spec_file(dir.path().join("a.yml")).map(|s| s.name).map_err(|e| e.to_string().replace("a.yml", "X"));
    let b = diffcassi::spec::load_spec_file(dir.path().join("b.yml")).map(|s| s.name).map_err(|e| e.to_string().replace("b.yml", "X"));
    assert_eq!(a, b);
    assert!(!format!("{b:?}").contains('\u{feff}'), "{b:?}");
}

/// `semi_diameter_mm` had no upper bound: 1e300 loaded and `embree-user` then failed on infinite bounds
/// naming no surface; a JSON integer 2⁶⁴ loaded too.
#[test]
fn semi_diameter_is_range_checked() {
    let dir = tempfile::tempdir().unwrap();
    let json = diffcassi::spec::to_json(&diffcassi::presets::spec("sp").unwrap()).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&json).unwrap();
    let surfaces = v["surfaces"].as_array().unwrap();
    let k = surfaces.iter().position(|s| s.get("semi_diameter_mm").is_some_and(|x| !x.is_null()) && s != &surfaces[0]).expect("a surface with a semi-diameter");
    v["surfaces"][k]["semi_diameter_mm"] = serde_json::json!(123.25);
    let body = serde_json::to_string_pretty(&v).unwrap();
    assert_eq!(body.matches("123.25").count(), 1);
    for (text, shown) in [("1e300", "1e300"), ("18446744073709551616", "1.8446744073709552e19"), ("-1", "-1")] {
        let p = dir.path().join("sd.json");
        std::fs::write(&p, body.replace("123.25", text)).unwrap();
        let e = diffcassi::spec::load_spec_file(&p).unwrap_err().to_string();
        assert!(e.contains(&format!("surface {k} ")) && e.contains("semi_diameter_mm") && e.contains(shown) && e.contains("<= 1e6 mm"), "{text}: {e}");
    }
    v["surfaces"][k]["semi_diameter_mm"] = serde_json::json!(1e6);
    std::fs::write(dir.path().join("ok.json"), serde_json::to_string(&v).unwrap()).unwrap();
    diffcassi::spec::load_spec_file(dir.path().join("ok.json")).unwrap();
}

/// The cosmetic messages of the round: a symbolic-link loop called "no such file", `missing key: shaper`,
/// a (4, 1) wavelength list "4 wavelengths for 4 bands", CR-only pupil CSVs read as one line, a NUL in a
/// header printed invisibly, `evaluate`'s hint naming commands that take no such option, a negative radiance
/// printed to 17 digits.
#[test]
fn cosmetic_messages_say_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::os::unix::fs::symlink(d.join("loop.npy"), d.join("loop.npy")).unwrap();
    let e = load_scene(&d.join("loop.npy"), None).unwrap_err().to_string();
    assert!(e.contains("symbolic links") && !e.contains("no such file"), "{e}");

    let mut raw = b"\x93NUMPY\x01\x00".to_vec();
    let dict = "{'descr': '<f8', 'fortran_order': False, }\n";
    raw.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    raw.extend_from_slice(dict.as_bytes());
    std::fs::write(d.join("noshape.npy"), &raw).unwrap();
    let e = diffcassi::io::read_npy_f64(d.join("noshape.npy")).unwrap_err().to_string();
    assert!(e.contains("missing key 'shape'") && !e.contains("shaper"), "{e}");

    diffcassi::io::write_npy_f32(d.join("c.npy"), &[2, 2, 4], &[0.5; 16]).unwrap();
    diffcassi::io::write_npy_f64(d.join("c_wavelengths_nm.npy"), &[4, 1], &[450.0, 500.0, 550.0, 600.0]).unwrap();
    let e = load_scene(&d.join("c.npy"), None).unwrap_err().to_string();
    assert!(e.contains("must be 1-D") && e.contains("[4, 1]"), "{e}");
    std::fs::remove_file(d.join("c_wavelengths_nm.npy")).unwrap();
    refused(d, &["evaluate", "--truth", "c.npy", "--estimate", "c.npy"], &["--truth", "--truth-wavelengths"]);
    let (_, out) = crate::cli_run::run_cli(d, &["evaluate", "--truth", "c.npy", "--estimate", "c.npy"]);
    assert!(!out.contains("render"), "{out}");

    let cols = diffcassi::io::parse_columns(Path::new("cr.csv"), "px,py\r0,0\r0.5,0\r", &["px", "py"]).unwrap();
    assert_eq!(cols, vec![vec![0.0, 0.5], vec![0.0, 0.0]]);
    let e = diffcassi::io::parse_columns(Path::new("nul.csv"), "px\0,py\n0,0\n", &["px", "py"]).unwrap_err().to_string();
    assert!(e.contains("available columns: px\\u{0}, py"), "{e}");

    let cube = SpectralCube::new(1, 1, vec![500.0], vec![-0.001], "t").unwrap();
    let e = diffcassi::render::settings::check_scene_values(&cube).unwrap_err();
    assert!(e.starts_with("scene value -0.001 at pixel (0, 0)"), "{e}");
}
