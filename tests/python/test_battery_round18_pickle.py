"""Held-out battery, round 18 (prober B, finding 3): a pickled or copied `System` was rebuilt from its spec as
JSON, which names its glass catalogue files by path, and the rebuild read the files again: one Sellmeier
coefficient of SCHOTT.AGF changed by 1e-4 (relative) after pickling moved the copy's landings by up to 5.6e-5 mm,
with no warning and the same `prescription_sha256`. A `System` now records each catalogue file's content
identity (`NAME (N bytes, crc32 X)`) when it is built, a copy carries it, and the rebuild refuses a file whose
content changed since, naming it. An unchanged catalogue still gives a copy equal bit for bit; a pickle of the
older form (`System.from_string(json, "json")`) still loads."""
import copy
import pathlib
import pickle
import shutil
import warnings

import numpy as np
import pytest

import diffcassi

FIXTURE = pathlib.Path(__file__).resolve().parents[1] / "fixtures" / "zmx" / "round15" / "duplicate_glass"


@pytest.fixture
def folder(tmp_path):
    d = tmp_path / "sys"
    shutil.copytree(FIXTURE, d)
    return d


def load(folder):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the fixture's duplicate glass warns at every load
        return diffcassi.System.from_file(str(folder / "duplicate_glass.zmx"))


def rebuild(make):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return make()


def edit_nbk7(folder):
    """Change N-BK7's first Sellmeier coefficient in SCHOTT.AGF by 1e-4 (relative), as the prober did."""
    p = folder / "SCHOTT.AGF"
    lines = p.read_text().splitlines()
    i = next(k for k, line in enumerate(lines) if line.startswith("NM N-BK7"))
    cd = lines[i + 1].split()
    assert cd[0] == "CD"
    cd[1] = repr(float(cd[1]) * 1.0001)
    lines[i + 1] = " ".join(cd)
    p.write_text("\n".join(lines) + "\n")


def landings(s, rays):
    return diffcassi.trace(s, *rays)["positions"]


def test_unchanged_catalogue_copies_bit_for_bit(folder):
    s = load(folder)
    rays = s.seeded_rays(50, [587.5618], 1)
    ref = landings(s, rays)
    for make in (lambda: pickle.loads(pickle.dumps(s)), lambda: copy.deepcopy(s), lambda: copy.copy(s)):
        c = rebuild(make)
        assert np.array_equal(landings(c, rays), ref)
        assert c.prescription_sha256() == s.prescription_sha256()
    # The identities a copy carries: the files by their content.
    carried = dict(s.__reduce__()[1][1])
    assert carried[str(folder / "SCHOTT.AGF")].startswith("SCHOTT.AGF (")
    assert "crc32" in carried[str(folder / "MYCAT.AGF")]


def test_catalogue_changed_after_pickling_is_refused_naming_it(folder):
    s = load(folder)
    blob = pickle.dumps(s)
    edit_nbk7(folder)
    for make in (lambda: pickle.loads(blob), lambda: copy.deepcopy(s)):
        with pytest.raises(diffcassi.DiffcassiValueError, match=r"glass catalogue .*SCHOTT\.AGF: its content changed since the system was built"):
            rebuild(make)


def test_catalogue_changed_before_pickling_is_refused_too(folder):
    """The identity is the one taken when the System was built, not when it was pickled."""
    s = load(folder)
    edit_nbk7(folder)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"SCHOTT\.AGF"):
        rebuild(lambda: pickle.loads(pickle.dumps(s)))


def test_copy_of_a_copy_checks_the_original_files_and_restored_content_loads(folder):
    s = load(folder)
    original = (folder / "SCHOTT.AGF").read_bytes()
    c = rebuild(lambda: copy.deepcopy(s))
    edit_nbk7(folder)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"SCHOTT\.AGF"):
        rebuild(lambda: pickle.loads(pickle.dumps(c)))
    (folder / "SCHOTT.AGF").write_bytes(original)  # the same bytes again (a newer mtime): the same glasses
    rays = s.seeded_rays(20, [587.5618], 2)
    assert np.array_equal(landings(rebuild(lambda: pickle.loads(pickle.dumps(c))), rays), landings(s, rays))


def test_missing_catalogue_is_named(folder):
    s = load(folder)
    blob = pickle.dumps(s)
    (folder / "MYCAT.AGF").unlink()
    with pytest.raises(diffcassi.DiffcassiError, match=r"MYCAT\.AGF"):
        rebuild(lambda: pickle.loads(blob))


class _OldPickle:
    """What a System pickled before round 18 reduced to: `System.from_string(json, "json")`."""

    def __init__(self, text):
        self.text = text

    def __reduce__(self):
        return (diffcassi.System.from_string, (self.text, "json"))


def test_old_style_pickle_still_loads(folder):
    s = load(folder)
    c = rebuild(lambda: pickle.loads(pickle.dumps(_OldPickle(s.to_json()))))
    assert isinstance(c, diffcassi.System)
    rays = s.seeded_rays(20, [587.5618], 3)
    assert np.array_equal(landings(c, rays), landings(s, rays))
    # … and it records the identities itself, so its own copies are checked.
    edit_nbk7(folder)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"SCHOTT\.AGF"):
        rebuild(lambda: copy.deepcopy(c))


def test_preset_copies_carry_no_catalogues():
    sp = diffcassi.System.preset("sp")
    assert sp.__reduce__()[1][1] == []
    assert pickle.loads(pickle.dumps(sp)).prescription_sha256() == sp.prescription_sha256()


def test_jacobian_refuses_a_catalogue_edited_since_the_system_was_built(folder):
    """`jacobian` (and `CassiRenderer`'s free parameters) assemble their glasses from the catalogue files again:
    an edit since the System was built is refused, naming the file, as a copy is — it traced the new glasses."""
    s = load(folder)
    rays = s.seeded_rays(8, [587.5618], 1)
    before = diffcassi.jacobian(s, "wavelength", *rays)["jacobian"]
    assert np.isfinite(before).all()
    edit_nbk7(folder)
    with pytest.raises(diffcassi.DiffcassiValueError, match="SCHOTT.AGF: its content changed since the system was built"):
        diffcassi.jacobian(s, "wavelength", *rays)
