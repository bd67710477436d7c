#!/usr/bin/env bash
# The diagnostic runs quoted in docs/REPRODUCTION.md ("Why results differ"), at make reproduce's size.
# Usage, from the repository root: bash docs/diagnostics/run.sh   (about 5 minutes on 2 cores)
# Each run prints its table; results, reports and an MLflow store go to .gtsweep_cache/diag/.
set -euo pipefail
B=${PYTHON:-.venv/bin/python}
D=.gtsweep_cache/diag
rm -rf "$D"; mkdir -p "$D"
C=(runner.progress=false "mlflow.tracking_uri=sqlite:///$PWD/$D/mlflow.db"
   dataset.n_synthetic=2 dataset.n_incremental=6 dataset.n_absolute=6)
# run NAME [-m] OVERRIDES...: the common overrides C first, so that a run's own overrides win
run() { local name=$1 flags=(); shift; if [ "$1" = -m ]; then flags=(-m); shift; fi; echo "== $name"
  "$B" -m gtsweep "${flags[@]}" "${C[@]}" "$@" > "$D/$name.log" 2>&1 || {
  tail -3 "$D/$name.log"; exit 1; }; grep -E '^(\*\*Survey|\|)' "$D/$name.log"; }

# XFeat's descriptor under the ratio test at 0.7 / 0.8 / 0.9 (incremental pairs), BRIEF beside it
run xfeat_ratio -m 'detector=[tuned/censure,tuned/akaze]' 'descriptor=[xfeat,brief]' 'transform=[incremental]' \
  matcher.bf_ratio.params.ratio=0.7,0.8,0.9 "hydra.sweep.dir=$D/xfeat_ratio"
# ... and with XFeat's own matcher: mutual nearest neighbours, no ratio test
run xfeat_mutual 'detector=[tuned/censure,tuned/akaze]' 'descriptor=[xfeat,brief]' 'transform=[incremental]' \
  "matcher=[mutual_nn]" "hydra.run.dir=$D/xfeat_mutual"
# CenSurE with OpenCV's default parameters (table4_incremental uses the tuned ones)
run censure_default 'detector=[censure]' 'descriptor=[orb,brief,latch]' 'transform=[incremental]' \
  "hydra.run.dir=$D/censure_default"
# CenSurE's border (1.5 x maxSize): tuned with maxSize 22, and tuned on 1288x964 views (the survey's image size)
run censure_maxsize22 'detector=[tuned/censure]' detector.censure.params.maxSize=22 'descriptor=[orb,brief,latch]' \
  'transform=[incremental]' "hydra.run.dir=$D/censure_maxsize22"
run censure_1288 'detector=[tuned/censure]' 'descriptor=[orb,brief,latch]' 'transform=[incremental]' \
  'dataset.view_size=[1288,964]' "hydra.run.dir=$D/censure_1288"
"$B" docs/diagnostics/border_overlap.py
"$B" docs/diagnostics/border_overlap.py --size 1288x964
# MSER, NMS against ANMS, with OpenCV's default parameters (table2_selectors uses the tuned ones)
run mser_default experiment=detection 'detector=[mser]' 'selector=[nms,anms]' \
  'transform=[rotation,translation,noise,gamma]' dataset.n_synthetic=1 "hydra.run.dir=$D/mser_default"
# SURF's ambiguity at OpenCV's hessianThreshold 100 and at the tuned one
run surf_default experiment=detection 'detector=[surf]' 'selector=[nms]' \
  'transform=[rotation,translation,noise,gamma]' dataset.n_synthetic=1 "hydra.run.dir=$D/surf_default"
run surf_tuned experiment=detection 'detector=[tuned/surf]' 'selector=[nms]' \
  'transform=[rotation,translation,noise,gamma]' dataset.n_synthetic=1 "hydra.run.dir=$D/surf_tuned"
