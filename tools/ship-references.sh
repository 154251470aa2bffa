#!/usr/bin/env bash
# Ships the tests' shared references: runs the test suite with GILAB_SHIP_REFERENCES set, so
# every reference `tests/common` reads (`shared_reference`, `shared_reference_images`,
# experiments' caches; rendered, or from target/tmp) is also written to tests/data/references/
# with a SOURCE stamp: the hash of the reference's footprint (`common::in_reference_footprint`,
# docs/testing.md#running-the-tests). Run it after the last change to the footprint (the engine,
# the scene, the shared shaders, the reference, Cargo.lock...; not another technique's or part's
# folder), then commit the folder: a fresh checkout (CI) then reads those references instead of
# rendering them. Arguments go to cargo test (e.g. `--no-fail-fast`, or `--test restir` to add
# one binary's references to an up-to-date folder).
set -euo pipefail
cd "$(dirname "$0")/.."
GILAB_SHIP_REFERENCES=1 cargo test --release "$@"
echo "shipped: $(ls tests/data/references/*.exr | wc -l) references, $(du -sh tests/data/references | cut -f1)"
