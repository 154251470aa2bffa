#!/usr/bin/env bash
# Ships the tests' shared references: runs the test suite with GILAB_SHIP_REFERENCES set, so
# every reference `tests/common::shared_reference` reads (rendered, or from target/tmp) is also
# written to tests/data/references/ with a SOURCE stamp of the sources it was rendered from.
# Run it after the last change to src/, shaders/ or Cargo.lock, then commit the folder: a fresh
# checkout (CI) then reads those references instead of rendering them. Arguments go to cargo
# test (e.g. `--test restir` to add one binary's references to an up-to-date folder).
set -euo pipefail
cd "$(dirname "$0")/.."
GILAB_SHIP_REFERENCES=1 cargo test --release "$@"
echo "shipped: $(ls tests/data/references/*.exr | wc -l) references, $(du -sh tests/data/references | cut -f1)"
