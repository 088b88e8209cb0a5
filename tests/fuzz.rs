//! Issue 16, class 6: a mutation fuzzer for every parser, on stable Rust, run by `cargo test` for a bounded
//! time. Each parser starts from the seed files in `tests/fuzz_corpus/<parser>/` and applies random
//! structure-unaware mutations (bit flips, interesting bytes, chunk deletion/duplication/insertion,
//! truncation, numbers replaced by extreme values, lines spliced); every input must give `Ok` or a clean
//! `Err` — a panic fails the test and saves the input to `target/fuzz-crashes/<parser>-<hash>.bin` (add it to
//! the corpus once fixed). An allocation abort would kill the test binary (also a failure).
//!
//! Budget: `DIFFCASSI_FUZZ_SECONDS` seconds per parser (default 2; 8 parsers, 2 at a time on 2 cores ≈ 8 s).
//! Longer run (docs/robustness.md): `DIFFCASSI_FUZZ_SECONDS=60 cargo test --release --test integration fuzz:: -- --nocapture`.
//! `DIFFCASSI_FUZZ_SEED` changes the random stream (default 1).
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn corpus_dir(parser: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz_corpus").join(parser)
}

fn seeds(parser: &str) -> Vec<Vec<u8>> {
    let dir = corpus_dir(parser);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())).map(|e| e.unwrap().path()).filter(|p| p.is_file()).collect();
    files.sort();
    let v: Vec<Vec<u8>> = files.iter().map(|p| std::fs::read(p).unwrap()).collect();
    assert!(!v.is_empty(), "empty corpus {}", dir.display());
    v
}

/// xorshift64*: deterministic, no dependency.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545F4914F6CDD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next() % n as u64) as usize
        }
    }
}

const EXTREMES: &[&str] = &["1e308", "-1e308", "1e-320", "0", "-0", "nan", "inf", "-inf", "NaN", "18446744073709551616", "4294967296", "-1", "999999999999", "1e9", "0.0", "", "\u{feff}", "\"", "[", "{", "&a", "*a"];
const BYTES: &[u8] = &[0, 0xff, 0x7f, 0x80, b'\n', b',', b':', b'"', b'-', b'.', b'e', b'[', b']', b'{', b'}', b'#', b'=', b' '];

fn mutate(rng: &mut Rng, input: &[u8], corpus: &[Vec<u8>]) -> Vec<u8> {
    let mut v = input.to_vec();
    for _ in 0..1 + rng.below(4) {
        let n = v.len();
        match rng.below(9) {
            0 if n > 0 => {
                let i = rng.below(n);
                v[i] ^= 1 << rng.below(8);
            }
            1 if n > 0 => {
                let i = rng.below(n);
                v[i] = BYTES[rng.below(BYTES.len())];
            }
            2 if n > 1 => {
                let a = rng.below(n);
                let b = (a + 1 + rng.below(64)).min(n);
                v.drain(a..b);
            }
            3 if n > 1 => {
                let a = rng.below(n);
                let b = (a + 1 + rng.below(64)).min(n);
                let chunk = v[a..b].to_vec();
                let at = rng.below(n);
                v.splice(at..at, chunk);
            }
            4 => v.truncate(rng.below(n + 1)),
            5 => {
                // Replace a number-looking token by an extreme value.
                let starts: Vec<usize> = (0..n).filter(|&i| v[i].is_ascii_digit() && (i == 0 || !v[i - 1].is_ascii_alphanumeric())).collect();
                if !starts.is_empty() {
                    let a = starts[rng.below(starts.len())];
                    let mut b = a;
                    while b < n && (v[b].is_ascii_digit() || v[b] == b'.' || v[b] == b'e' || v[b] == b'-') {
                        b += 1;
                    }
                    v.splice(a..b, EXTREMES[rng.below(EXTREMES.len())].bytes());
                }
            }
            6 => {
                let at = rng.below(n + 1);
                v.splice(at..at, EXTREMES[rng.below(EXTREMES.len())].bytes());
            }
            7 => {
                // Splice lines from another corpus file.
                let other = &corpus[rng.below(corpus.len())];
                let a = rng.below(other.len() + 1);
                let b = (a + rng.below(200)).min(other.len());
                let at = rng.below(n + 1);
                v.splice(at..at, other[a..b].iter().copied());
            }
            _ if n > 0 => {
                // Duplicate a line many times (size blow-up).
                let text_lines: Vec<usize> = (0..n).filter(|&i| v[i] == b'\n').collect();
                if text_lines.len() >= 2 {
                    let k = rng.below(text_lines.len() - 1);
                    let line = v[text_lines[k]..text_lines[k + 1]].to_vec();
                    let reps = 1 + rng.below(50);
                    for _ in 0..reps {
                        v.splice(text_lines[k]..text_lines[k], line.iter().copied());
                    }
                }
            }
            _ => {}
        }
    }
    v
}

fn budget() -> Duration {
    let s: f64 = std::env::var("DIFFCASSI_FUZZ_SECONDS").ok().and_then(|s| s.parse().ok()).filter(|s: &f64| s.is_finite() && *s >= 0.0).unwrap_or(2.0);
    Duration::from_secs_f64(s)
}

/// Run `target` on the seeds and on mutations until the time budget is spent; panics are failures.
fn fuzz(parser: &str, target: impl Fn(&[u8]) -> bool) {
    let corpus = seeds(parser);
    let seed: u64 = std::env::var("DIFFCASSI_FUZZ_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(1);
    let mut rng = Rng(seed.wrapping_mul(0x9E3779B97F4A7C15) ^ parser.bytes().fold(0xcbf29ce484222325u64, |h, b| (h ^ b as u64).wrapping_mul(0x100000001b3)) | 1);
    // The seeds themselves must parse (the fuzzer starts from valid inputs).
    for (k, s) in corpus.iter().enumerate() {
        assert!(target(s), "{parser}: corpus file {k} does not parse");
    }
    let t0 = Instant::now();
    let (mut runs, mut accepted) = (0u64, 0u64);
    let mut current = corpus[0].clone();
    while t0.elapsed() < budget() || runs < 20 {
        if rng.below(8) == 0 {
            current = corpus[rng.below(corpus.len())].clone();
        }
        let input = mutate(&mut rng, &current, &corpus);
        let r = catch_unwind(AssertUnwindSafe(|| target(&input)));
        runs += 1;
        match r {
            Ok(ok) => {
                if ok {
                    accepted += 1;
                    // Keep exploring from inputs that still parse.
                    current = input;
                }
            }
            Err(_) => {
                let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/fuzz-crashes");
                std::fs::create_dir_all(&dir).unwrap();
                let h = input.iter().fold(0xcbf29ce484222325u64, |h, b| (h ^ *b as u64).wrapping_mul(0x100000001b3));
                let p = dir.join(format!("{parser}-{h:016x}.bin"));
                std::fs::write(&p, &input).unwrap();
                panic!("{parser}: panic on a mutated input after {runs} runs, saved to {}", p.display());
            }
        }
    }
    eprintln!("fuzz {parser}: {runs} inputs in {:.1} s ({accepted} accepted, the rest clean errors), no panic", t0.elapsed().as_secs_f64());
}

/// For readers that take a path: write the bytes to a per-thread file with the right extension.
fn via_file(name: &str, bytes: &[u8], read: impl Fn(&Path) -> bool) -> bool {
    let dir = std::env::temp_dir().join(format!("diffcassi-fuzz-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    read(&p)
}

#[test]
fn fuzz_spec_toml() {
    fuzz("toml", |b| {
        let text = String::from_utf8_lossy(b);
        match diffcassi::spec::from_toml(&text, "f.toml") {
            Ok(s) => {
                // A spec that parses must also build or fail cleanly, and a built system trace cleanly.
                let _ = diffcassi::system::SequentialSystem::build(&s);
                true
            }
            Err(e) => {
                assert!(!e.to_string().is_empty());
                false
            }
        }
    });
}

#[test]
fn fuzz_spec_json() {
    fuzz("json", |b| {
        let text = String::from_utf8_lossy(b);
        match diffcassi::spec::from_json(&text, "f.json") {
            Ok(s) => {
                let _ = diffcassi::system::SequentialSystem::build(&s);
                true
            }
            Err(_) => false,
        }
    });
}

#[test]
fn fuzz_spec_yaml() {
    fuzz("yaml", |b| {
        let text = String::from_utf8_lossy(b);
        match diffcassi::spec::yaml::import_yaml(&text, "f.yml") {
            Ok(s) => {
                let _ = diffcassi::system::SequentialSystem::build(&s);
                true
            }
            Err(_) => false,
        }
    });
}

#[test]
fn fuzz_zemax_csv() {
    use diffcassi::spec::zemax_csv::{import_prescription, SystemData};
    let data = SystemData::paper_defaults();
    fuzz("zemax_csv", |b| {
        let text = String::from_utf8_lossy(b);
        match import_prescription(&text, "f.csv", &data) {
            Ok(s) => {
                let _ = diffcassi::system::SequentialSystem::build(&s);
                true
            }
            Err(_) => false,
        }
    });
}

#[test]
fn fuzz_agf() {
    fuzz("agf", |b| diffcassi::materials::GlassCatalog::from_agf_bytes(b, "F.AGF").is_ok());
}

#[test]
fn fuzz_npy() {
    fuzz("npy", |b| via_file("f.npy", b, |p| diffcassi::io::read_npy_f64(p).is_ok()));
}

#[test]
fn fuzz_exr() {
    fuzz("exr", |b| via_file("f.exr", b, |p| diffcassi::scene::load_scene(p, None).is_ok()));
}

#[test]
fn fuzz_png_mask() {
    fuzz("png", |b| via_file("f.png", b, |p| diffcassi::render::Mask::load(p).is_ok()));
}

/// Writes the binary seeds (NPY, EXR, PNG) with the crate's own writers; run once with `--ignored` when
/// the corpus needs regenerating. The text seeds are exported specs and the shipped prescription.
#[test]
#[ignore]
fn write_seed_corpus() {
    let d = |p: &str| {
        let d = corpus_dir(p);
        std::fs::create_dir_all(&d).unwrap();
        d
    };
    diffcassi::io::write_npy_f64(d("npy").join("a.npy"), &[3, 4], &(0..12).map(|i| i as f64 * 0.1).collect::<Vec<_>>()).unwrap();
    diffcassi::io::write_npy_f32(d("npy").join("b.npy"), &[2, 2, 3], &(0..12).map(|i| i as f32).collect::<Vec<_>>()).unwrap();
    diffcassi::io::write_npy_u8(d("npy").join("c.npy"), &[4, 4], &[0, 1, 0, 1, 1, 0, 1, 0, 0, 0, 1, 1, 1, 1, 0, 0]).unwrap();
    let cube = diffcassi::scene::synthetic_scene(6, 5, &[450.0, 550.0, 650.0], 1);
    diffcassi::scene::save_exr(&cube, &d("exr").join("a.exr")).unwrap();
    diffcassi::render::Mask::random(8, 8, 0.5, 3).unwrap().save_png(&d("png").join("a.png")).unwrap();
    let spec = diffcassi::presets::spec("sp").unwrap();
    std::fs::write(d("toml").join("sp.toml"), diffcassi::spec::to_toml(&spec).unwrap()).unwrap();
    std::fs::write(d("json").join("sp.json"), diffcassi::spec::to_json(&spec).unwrap()).unwrap();
    std::fs::write(d("zemax_csv").join("sp.csv"), diffcassi::presets::prescription_csv("sp").unwrap()).unwrap();
}
