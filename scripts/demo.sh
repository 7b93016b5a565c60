#!/usr/bin/env bash
# The built-in example: synthesize a rig recording with a concealed effect, run the ROS node
# graph on it (recorded to an MCAP bag), analyse it offline, and say where the report is.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
OUT="${1:-demo}"
cd "$ROOT"
rm -rf "$OUT/rec" "$OUT/rec.truth.json" "$OUT/analysis" "$OUT/bag" "$OUT/bag.logs"
mkdir -p "$OUT"
echo "== 1/3 synthesize a 1.5 s, 1500-frame rig recording as a lab sees one: COR scatter 0.015 per impact,"
echo "        camera noise 2 gray levels, accelerometers 0.4 ms off the camera clock, and a concealed effect"
echo "        (Coulomb friction on the guide rods) for the analysis to find"
./vibro synth --out "$OUT/rec" --seed 7 --effect coulomb_friction --param force_n=1.5e-4 \
  --cor-scatter 0.015 --noise 2 --clock-offset-ms 0.4
echo "== 2/3 run the node graph (separate processes over DDS), recorded to $OUT/bag"
./vibro graph "$OUT/rec" --bag "$OUT/bag"
echo "== 3/3 offline analysis of the same recording"
./vibro analyze "$OUT/rec" --out "$OUT/analysis"
echo
echo "demo: report     $OUT/analysis/report.html"
echo "demo: results    $OUT/analysis/results.json   (from the bag: ./vibro results $OUT/bag)"
echo "demo: truth      $OUT/rec.truth.json (what the synthetic rig really did; the analysis never reads it)"
