#!/usr/bin/env bash
# The built-in example: synthesize a rig recording with a concealed effect, analyse it,
# and say where the report is. Runs whatever stages exist in this checkout.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
OUT="${1:-demo}"
cd "$ROOT"
has() { ./vibro --help | grep -qE "^    $1 "; }
mkdir -p "$OUT"
if has synth && has analyze; then
  rm -rf "$OUT/rec" "$OUT/rec.truth.json" "$OUT/analysis"
  ./vibro synth --out "$OUT/rec" --seed 7 --effect coulomb_friction --param force_n=2.0e-4
  ./vibro analyze "$OUT/rec" --out "$OUT/analysis"
  echo "demo: report at $OUT/analysis/report.html (truth of the synthetic run: $OUT/rec.truth.json)"
else
  echo "demo: synth/analyze not available yet; validating the committed fixture recording"
  ./vibro info tests/fixtures/tiny_recording
fi
