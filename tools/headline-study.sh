#!/usr/bin/env bash
# The headline study (issue 59, presets/studies/headline.toml) on a GPU in one call: runs
# `gilab study`, then packs the report (without the per-run images in scenes/*/runs/, which are
# large EXRs) as headline-report.tar.gz, split into parts of at most 15 MiB.
#
# On your own GPU, `gilab study presets/studies/headline.toml` is all it takes (the report lands
# in out/study/headline/); this script adds the packing for a machine you reach only through
# files, like the project's lent GPU machine.
#
# On the project's lent GPU machine (../shared/NOTES-device.md: the machine has no toolchain,
# so carry .dev/gilab built here and the Vulkan loader debs in .gl/):
#   device command: bash tools/headline-study.sh        carry: [".gl", ".dev"]
# $OUT (set by the device tool) receives the parts; unpack here with
#   cat headline-report.tar.gz.part-* | tar -xz -C docs/results/<date>-<gpu>/
#
# Environment: LIMIT (seconds before the study is stopped, default 540: one 10-minute call
# with time to pack; the report written after each scene survives a stop), STUDY_ARGS (e.g.
# "--size 1280x720", or "--scenes metal,mirror" to run only those now), CACHE (reference cache
# folder), REPORT (the full report folder; default a temporary one), PREVIOUS (an unpacked
# earlier report of this study, cut short: it is continued with --resume, its scenes kept).
set -u
cd "$(dirname "$0")/.."
G=target/release/gilab
if [ -d .gl ]; then
  # The lent device: the Vulkan loader from .gl/, NVIDIA's driver.
  for f in .gl/*.deb; do dpkg -x "$f" /; done
  ldconfig
  export VK_DRIVER_FILES=${VK_DRIVER_FILES:-/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json}
  export GILAB_BACKEND=vulkan
fi
[ -x .dev/gilab ] && G=.dev/gilab
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp/xdg}
mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"
OUT=${OUT:-out/study}
REPORT=${REPORT:-$(mktemp -d)/headline}
mkdir -p "$OUT" "$REPORT"
RESUME=""
if [ -n "${PREVIOUS:-}" ]; then
  cp -r "$PREVIOUS"/. "$REPORT"/
  RESUME=--resume
fi
{
  # Appended: a resumed report keeps each invocation's machine.
  echo "== $(date -u)"
  nvidia-smi --query-gpu=name,driver_version,clocks.gr,clocks.max.gr --format=csv 2>&1 || true
  git log -1 --format='%H %s' 2>/dev/null || true
} >> "$REPORT/machine.txt"
start=$(date +%s)
# shellcheck disable=SC2086 # STUDY_ARGS is a list of arguments
timeout "${LIMIT:-540}" "$G" study presets/studies/headline.toml --out "$REPORT" \
  --cache "${CACHE:-cache/reference}" $RESUME ${STUDY_ARGS:-} >> "$REPORT/study.log" 2>&1
status=$?
echo "gilab study: exit $status after $(( $(date +%s) - start )) s" | tee -a "$REPORT/study.log"
tar -C "$REPORT" --exclude='./scenes/*/runs' -czf - . | split -b 15M - "$OUT/headline-report.tar.gz.part-"
ls -la "$OUT"
tail -c 4000 "$REPORT/study.log"
