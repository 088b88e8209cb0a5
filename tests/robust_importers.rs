//! Issue 16, class 1: strict importers. A broken file is an error naming the file, line and problem —
//! never a system silently different from the file (a glass turned into air, a lens surface used as the
//! image, TOML written into a `.yaml`).
use diffcassi::prelude::*;
use diffcassi::spec::zemax_csv::{import_prescription, SystemData};

fn sp_csv() -> String {
    presets::prescription_csv("sp").unwrap().to_string()
}

fn import(text: &str) -> Result<diffcassi::spec::SystemSpec, String> {
    import_prescription(text, "user.csv", &SystemData::paper_defaults()).map_err(|e| e.to_string())
}

fn lines_of(text: &str) -> Vec<String> {
    text.lines().map(String::from).collect()
}

fn assert_mentions(msg: &str, parts: &[&str]) {
    for p in parts {
        assert!(msg.contains(p), "error `{msg}` should mention `{p}`");
    }
}

#[test]
fn the_shipped_prescriptions_still_import() {
    for name in ["sp", "ap", "msp", "map"] {
        let csv = presets::prescription_csv(name).unwrap();
        import(csv).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
}

#[test]
fn truncated_last_row_is_an_error() {
    let good = sp_csv();
    let body = good.trim_end();
    // Cut the IMAGE row after each of several characters: never a silently shorter system.
    let last_start = body.rfind('\n').unwrap() + 1;
    let mut cases = 0;
    for cut in (last_start + 1)..body.len() {
        let text = &body[..cut];
        let e = import(text).expect_err(&format!("cut at {cut}: `{}`", &body[last_start..cut]));
        assert!(e.contains("user.csv") && e.contains("line"), "{e}");
        cases += 1;
    }
    assert!(cases > 10);
    // Dropping the whole IMAGE row: the last lens surface must not become the image.
    let without_image: String = body[..last_start].to_string();
    assert_mentions(&import(&without_image).unwrap_err(), &["user.csv", "IMAGE"]);
}

#[test]
fn a_row_with_fewer_fields_than_the_header_is_an_error() {
    // Row 6 (N-BK7 prism) without its trailing empty columns: formerly read as-is; and with the material
    // column missing (the glass would become air).
    let good = sp_csv();
    let mut l = lines_of(&good);
    let k = l.iter().position(|s| s.starts_with("6,Standard")).unwrap();
    l[k] = "6,Standard,,inf,6.000,N-BK7".into();
    assert_mentions(&import(&l.join("\n")).unwrap_err(), &["user.csv", &format!("line {}", k + 1), "6 fields", "13"]);
    l[k] = "6,Standard,,inf,6.000,4.941,0,,,,,".into();
    assert_mentions(&import(&l.join("\n")).unwrap_err(), &["line", "12 fields"]);
    // Too many fields too.
    l[k] = format!("{},", good.lines().nth(k).unwrap());
    assert_mentions(&import(&l.join("\n")).unwrap_err(), &["14 fields"]);
}

#[test]
fn object_and_image_rows_are_required_in_place() {
    let good = sp_csv();
    let l = lines_of(&good);
    let obj = l.iter().position(|s| s.starts_with("0,OBJECT")).unwrap();
    // OBJECT renamed to a plain surface.
    let mut m = l.clone();
    m[obj] = m[obj].replacen("OBJECT Standard", "Standard", 1);
    assert_mentions(&import(&m.join("\n")).unwrap_err(), &["surface 0", "OBJECT"]);
    // IMAGE marker in the middle.
    let mut m = l.clone();
    let k = m.iter().position(|s| s.starts_with("12,Standard")).unwrap();
    m[k] = m[k].replacen("12,Standard", "12,IMAGE Standard", 1);
    assert_mentions(&import(&m.join("\n")).unwrap_err(), &["surface 12", "IMAGE", "last"]);
}

#[test]
fn a_utf8_bom_is_accepted() {
    let good = sp_csv();
    let with_bom = format!("\u{feff}{good}");
    assert_eq!(import(&with_bom).unwrap(), import(&good).unwrap());
    // And through the file loader (bytes on disk).
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bom.csv");
    std::fs::write(&p, with_bom.as_bytes()).unwrap();
    diffcassi::spec::load_spec_file(&p).unwrap();
}

#[test]
fn export_spec_format_follows_the_extension() {
    let spec = presets::spec("sp").unwrap();
    let dir = tempfile::tempdir().unwrap();
    for bad in ["x.yaml", "x.yml", "x.csv", "x.txt", "noext"] {
        let p = dir.path().join(bad);
        let e = diffcassi::spec::save_spec_file(&spec, &p).unwrap_err().to_string();
        assert_mentions(&e, &[bad, ".toml or .json"]);
        assert!(!p.exists(), "{bad} written");
    }
    for good in ["x.toml", "x.TOML", "x.json", "x.JSON"] {
        let p = dir.path().join(good);
        diffcassi::spec::save_spec_file(&spec, &p).unwrap();
        let back = diffcassi::spec::load_spec_file(&p).unwrap();
        assert_eq!(back, spec, "{good}");
    }
    // The content really is JSON for .json.
    let text = std::fs::read_to_string(dir.path().join("x.json")).unwrap();
    serde_json::from_str::<serde_json::Value>(&text).unwrap();
}

#[test]
fn a_binary_glass_catalogue_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("GARBAGE.AGF");
    let bin = std::fs::read(env!("CARGO_BIN_EXE_diffcassi")).unwrap();
    std::fs::write(&p, &bin[..bin.len().min(1 << 16)]).unwrap();
    let e = diffcassi::materials::GlassCatalog::from_agf_file(&p).unwrap_err().to_string();
    assert!(e.contains("GARBAGE.AGF"), "{e}");
    let empty = dir.path().join("EMPTY.AGF");
    std::fs::write(&empty, "CC nothing here\n").unwrap();
    let e = diffcassi::materials::GlassCatalog::from_agf_file(&empty).unwrap_err().to_string();
    assert_mentions(&e, &["EMPTY.AGF", "no glass"]);
}
