#!/usr/bin/env bash
# Checks that every cargo selection the test command builds resolves the `diffcassi` library's dependencies with
# the same features, so the library is compiled once and shared (crates/workspace-hack/Cargo.toml says why).
# Selections: `cargo test` at the root (with its dev-dependencies), the C++ bridge (`cargo test -p diffcassi-cpp`
# and the CMake build's `cargo build -p diffcassi-cpp --lib`), the CLI alone (`cargo build -p diffcassi --bin`),
# maturin's `-p diffcassi-python`. Prints each dependency whose features differ and exits 1; silent when none.
# Fix a report by adding the union of the listed features to crates/workspace-hack/Cargo.toml.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
target=$(rustc -vV | sed -n 's/^host: //p')
tree() { cargo tree --locked --target "$target" --prefix none -f '{p}|{f}' "$@" | sed 's/ (\*)$//' | sort -u; }
tree -p diffcassi -e normal,build,dev >"$tmp/test"
tree -p diffcassi-cpp -e normal,build,dev >"$tmp/cpp-test"
tree -p diffcassi-cpp -e normal,build >"$tmp/cpp-lib"
tree -p diffcassi -e normal,build >"$tmp/cli"
tree -p diffcassi-python -e normal,build >"$tmp/python"
python3 - "$tmp" <<'PY'
import collections, pathlib, sys
tmp = pathlib.Path(sys.argv[1])
names = ["test", "cpp-test", "cpp-lib", "cli", "python"]
sel = {}
for n in names:
    d = collections.defaultdict(set)
    for line in (tmp / n).read_text().splitlines():
        pkg, feats = line.split("|", 1)
        d[pkg].add(feats)
    sel[n] = d
bad = []
for pkg in sorted(sel["cli"]):  # the library's own dependency graph (and the library itself)
    got = {n: " / ".join(sorted(sel[n].get(pkg, {"(absent)"}))) for n in names}
    if len(set(got.values())) > 1:
        bad.append(f"  {pkg}: " + "; ".join(f"{n} [{v}]" for n, v in got.items()))
if bad:
    print("check_feature_unity: the library's dependencies resolve with different features per selection, so "
          "the test command compiles the library more than once; add the union to crates/workspace-hack/Cargo.toml:",
          *bad, sep="\n", file=sys.stderr)
    sys.exit(1)
PY
