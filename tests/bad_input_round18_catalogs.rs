//! Round 18 of the held-out battery (3 Dec 2026, prober B): a copy of a Python `System` (pickle, `copy`) was
//! rebuilt from its spec, which names glass catalogues by path, and read files edited since the original was
//! built — other refractive indices under the same prescription hash. The library now names a catalogue file
//! by its content (`GlassCatalog::entry_identity`, shared with a dataset's configuration), a system's files are
//! identified before they are read (`SequentialSystem::catalog_identities`) and a rebuild checks them
//! (`check_catalog_identities`): a changed file is an error naming it.
use diffcassi::materials::GlassCatalog;
use diffcassi::system::SequentialSystem;

const FIXTURE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/zmx/round15/duplicate_glass");

fn copy_fixture(dir: &std::path::Path) {
    for f in ["duplicate_glass.zmx", "SCHOTT.AGF", "MYCAT.AGF"] {
        std::fs::copy(std::path::Path::new(FIXTURE).join(f), dir.join(f)).unwrap();
    }
}

#[test]
fn catalogue_identities_are_taken_by_content_and_a_changed_file_is_named() {
    let dir = tempfile::tempdir().unwrap();
    copy_fixture(dir.path());
    let spec = diffcassi::spec::load_spec_file(&dir.path().join("duplicate_glass.zmx")).unwrap();
    let ids = SequentialSystem::catalog_identities(&spec);
    let schott = dir.path().join("SCHOTT.AGF");
    let len = std::fs::metadata(&schott).unwrap().len();
    let (entry, id) = ids.iter().find(|(e, _)| e.ends_with("SCHOTT.AGF")).expect("SCHOTT.AGF identified");
    assert_eq!(std::path::Path::new(entry), schott);
    assert!(id.starts_with(&format!("SCHOTT.AGF ({len} bytes, crc32 ")), "{id}");
    SequentialSystem::build(&spec).unwrap();
    SequentialSystem::check_catalog_identities(&ids).unwrap();
    // The same bytes rewritten (a newer modification time): the same identity.
    let original = std::fs::read(&schott).unwrap();
    std::fs::write(&schott, &original).unwrap();
    SequentialSystem::check_catalog_identities(&ids).unwrap();
    // One digit of a coefficient changed: refused, naming the file.
    let edited = String::from_utf8(original.clone()).unwrap().replacen("1.03961212", "1.03971208", 1);
    assert_ne!(edited.as_bytes(), &original[..], "the fixture's N-BK7 coefficient");
    std::fs::write(&schott, edited).unwrap();
    let e = SequentialSystem::check_catalog_identities(&ids).unwrap_err().to_string();
    assert!(e.contains(&format!("glass catalogue {}", schott.display())) && e.contains("changed since the system was built"), "{e}");
    // A file that is gone is left to the rebuild, which names it.
    std::fs::remove_file(&schott).unwrap();
    SequentialSystem::check_catalog_identities(&ids).unwrap();
    let e = SequentialSystem::build(&spec).unwrap_err().to_string();
    assert!(e.contains("SCHOTT.AGF"), "{e}");
}

#[test]
fn built_in_catalogues_have_no_file_identity() {
    assert!(GlassCatalog::entry_identity("builtin:OHARA").is_none());
    assert!(GlassCatalog::entry_identity("BUILTIN:SCHOTT").is_none());
    assert!(matches!(GlassCatalog::entry_identity("/nonexistent/X.AGF"), Some(Err(_))));
}

/// The Jacobian's parameter set assembles the system's catalogues as the build does: a `builtin:NAME` entry was
/// read as a file path ("cannot read glass catalogue builtin:OHARA: No such file or directory"), so
/// `diffcassi.jacobian` failed on any system naming a built-in catalogue.
#[test]
fn jacobian_parameter_set_reads_built_in_catalogue_entries() {
    let mut spec = diffcassi::presets::spec("sp").unwrap();
    spec.glass_catalogs.push("builtin:OHARA".into());
    let sys = SequentialSystem::build(&spec).unwrap();
    let set = diffcassi::diff::ParamSet::for_system(&sys, "prism_tilt_x").unwrap();
    assert_eq!(set.spec.glass_catalogs, spec.glass_catalogs);
}
