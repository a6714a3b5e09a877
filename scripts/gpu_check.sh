#!/usr/bin/env bash
# Check a cliport install on a CUDA machine, in stages that each record their result in an output folder, so that
# running the script again with the same --out skips what is done and continues the rest (a stopped cell training
# resumes from its last save). A summary table ends every run.
#
#   tests   the CUDA tests (pytest -m gpu): the captured training step, CUDA-graph acting, the speed settings
#   bench   scripts/bench_train.py at the published size (batch 1 and 8), beside the reference CLIPort's released
#           code when --reference-dir names its folder
#   cell    (with --cell) the seed reproduction's 40k-step cell: transporter_only, ravens recipe, assembling-kits,
#           100 demos, batch 1, published size, then its 100 test episodes (on one H200: about 9 minutes of training,
#           2 of testing, and the demos before them)
#
# Usage: bash scripts/gpu_check.sh [--out DIR] [--reference-dir DIR] [--cell] [--data-dir DIR] [--stages "S ..."]
#                                  [--python PY] [--cpu] [--dry-run]
#   --out DIR            where the logs, results and the cell's run go (default ~/cliport-gpu-check; keep it
#                        outside the checkout, so that a new checkout finds it)
#   --reference-dir DIR  the reference CLIPort folder (holding ref_bench.py) to benchmark beside
#   --cell               add the cell to the stages
#   --data-dir DIR       the cell's assembling-kits demos (default: made in DIR/cell/data by cliport-demos)
#   --stages "S ..."     the stages to run, of: tests bench cell (default: tests bench, and cell with --cell)
#   --python PY          the Python that has cliport installed (default: $PY, else the checkout's .venv, else
#                        python3)
#   --cpu                the smoke run (also SMOKE=1): every stage tiny on a CPU, to check the script and the install
#                        without a GPU (the CUDA tests then skip)
#   --dry-run            print each stage's state and the commands it would run, and run nothing
set -uo pipefail

usage() { sed -n '2,/^$/p' "$0" | sed 's/^# \{0,1\}//'; }
fail() { echo "error: gpu_check.sh: $1" >&2; exit 2; }

ROOT=$(cd "$(dirname "$0")/.." && pwd)
OUT=${OUT:-$HOME/cliport-gpu-check}
REF=""
DATA=""
CELL=""
STAGES=""
CPU=${SMOKE:-}
DRY=""
PY=${PY:-}
while [ $# -gt 0 ]; do
  case $1 in
    -h|--help) usage; exit 0 ;;
    --out|--reference-dir|--data-dir|--stages|--python)
      [ $# -ge 2 ] && [ -n "$2" ] || fail "$1 needs a value (see --help)"
      case $1 in
        --out) OUT=$2 ;; --reference-dir) REF=$2 ;; --data-dir) DATA=$2 ;; --stages) STAGES=$2 ;; --python) PY=$2 ;;
      esac
      shift 2 ;;
    --cell) CELL=1; shift ;;
    --cpu) CPU=1; shift ;;
    --dry-run) DRY=1; shift ;;
    *) fail "unknown option $1 (see --help)" ;;
  esac
done
[ -n "$STAGES" ] || STAGES="tests bench${CELL:+ cell}"
for stage in $STAGES; do
  case $stage in tests|bench|cell) ;; *) fail "unknown stage $stage: choose from tests, bench, cell" ;; esac
done
[ -z "$REF" ] || [ -f "$REF/ref_bench.py" ] || fail "--reference-dir $REF holds no ref_bench.py"
[ -z "$DATA" ] || [ -d "$DATA/assembling-kits-train" ] || fail "--data-dir $DATA holds no assembling-kits-train demos"
if [ -z "$PY" ]; then
  if [ -x "$ROOT/.venv/bin/python" ]; then PY=$ROOT/.venv/bin/python; else PY=python3; fi
fi
OUT=$(realpath -m "$OUT")
case "$OUT/" in
  "$ROOT"/*) echo "note: $OUT is inside the checkout; a fresh checkout will not find its results" >&2 ;;
esac
LOGS=$OUT/logs
STATE=$OUT/state
[ -n "$DRY" ] || mkdir -p "$LOGS" "$STATE" 2>/dev/null || fail "cannot make the output folder $OUT"

# What each stage runs: published sizes on a GPU, tiny ones on a CPU.
if [ -n "$CPU" ]; then
  DEVICE=cpu
  GPU_TESTS=(tests/agents/test_cuda_speed.py)
  BENCH=(--device cpu --agents transporter_only --batch-sizes 1 --steps 2 --log-every 1 --n-rotations 4
         --act-repeats 1 --n-demos 2 --num-workers 0 --reference-steps 1)
  DEMOS=(--n 2 --camera-scale 0.5)
  TRAIN=(--device cpu --n-demos 2 --n-steps 30 --checkpoint-steps 10 30 --save-last-every 10 --width 0.125
         --n-rotations 4 --camera-scale 0.5 --num-workers 0)
  STEPS=30; EPISODES=2
else
  DEVICE=cuda
  GPU_TESTS=(tests)
  BENCH=(--profile)
  DEMOS=(--n 100)
  TRAIN=(--n-demos 100 --n-steps 40000 --checkpoint-steps 1000 2000 5000 10000 20000 40000 --save-last-every 2000)
  STEPS=40000; EPISODES=100
fi
[ -n "$REF" ] && BENCH+=(--reference-dir "$REF")
CELL_DIR=$OUT/cell
RUN=$CELL_DIR/run
DATA=${DATA:-$CELL_DIR/data}
FINAL=$(printf "%s/checkpoints/step-%06d.pt" "$RUN" "$STEPS")
WORKERS=$(( $(nproc) - 2 )); [ $WORKERS -gt $EPISODES ] && WORKERS=$EPISODES; [ $WORKERS -lt 1 ] && WORKERS=1

# run LOG CMD...: run a command (its output to LOG), or print it in a dry run; returns its status.
run() {
  local log=$1; shift
  if [ -n "$DRY" ]; then echo "  would run: $* > $log"; return 0; fi
  echo "[$(date +%T)] $*" >>"$log"
  (cd "$ROOT" && "$@") >>"$log" 2>&1
}
done_mark() { [ -e "$STATE/$1.done" ]; }
want() { [[ " $STAGES " == *" $1 "* ]]; }

if [ -z "$DRY" ]; then
  "$PY" -c "import cliport, torch" 2>/dev/null || fail "$PY cannot import cliport and torch: pass --python, or install"
  if [ -z "$CPU" ]; then
    "$PY" -c "import torch, sys; sys.exit(not torch.cuda.is_available())" ||
      fail "torch sees no CUDA device here: check the driver, or run the CPU smoke run with --cpu"
  fi
fi
echo "gpu_check: stages ($STAGES) on $DEVICE, results in $OUT"

stage_tests() {
  local log=$LOGS/tests.log
  run "$log" "$PY" -m pytest -q -p no:cacheprovider -o addopts="" -m gpu -rs "${GPU_TESTS[@]}"
  local rc=$?
  [ -n "$DRY" ] && return 0
  tail -n 1 "$log" >"$STATE/tests.result"
  [ $rc -eq 0 ] && touch "$STATE/tests.done"
}

stage_bench() {
  run "$LOGS/bench.log" "$PY" scripts/bench_train.py "${BENCH[@]}" --out "$STATE/bench.json" &&
    { [ -n "$DRY" ] || touch "$STATE/bench.done"; }
}

stage_cell() {
  local log=$LOGS/cell.log
  if [ ! -d "$DATA/assembling-kits-train" ] || [ "$DATA" = "$CELL_DIR/data" ]; then
    # cliport-demos resumes: the demos already there are kept.
    run "$log" "$PY" -m cliport.cli.demos --task assembling-kits --mode train "${DEMOS[@]}" --data-dir "$DATA" \
      --no-progress || return 1
  fi
  if [ ! -e "$FINAL" ]; then
    if [ -e "$RUN/config.json" ]; then
      run "$log" "$PY" -m cliport.cli.train --resume --run-dir "$RUN" --no-progress || return 1
    else
      run "$log" "$PY" -m cliport.cli.train --agent transporter_only --recipe ravens --task assembling-kits \
        --batch-size 1 --data-dir "$DATA" --run-dir "$RUN" --val-episodes 0 --checkpoint-every 0 "${TRAIN[@]}" \
        --no-progress || return 1
    fi
  fi
  run "$log" "$PY" -m cliport.cli.eval --run-dir "$RUN" --mode test --n-episodes "$EPISODES" --checkpoint "$STEPS" \
    --workers "$WORKERS" --out "$CELL_DIR/eval" --no-progress || return 1
  [ -n "$DRY" ] || { cp "$CELL_DIR/eval/assembling-kits-test-$STEPS.json" "$STATE/cell.json" && touch "$STATE/cell.done"; }
}

for stage in tests bench cell; do
  want $stage || continue
  if done_mark $stage; then
    echo "$stage: done before (remove $STATE/$stage.done to run it again)"
    continue
  fi
  echo "$stage: running (log: $LOGS/$stage.log)"
  "stage_$stage" || echo "$stage: failed (see $LOGS/$stage.log)"
done

# The summary table (also OUT/summary.txt); the script's status is 0 when every stage asked for is done.
"$PY" - "$OUT" "$STAGES" "$STEPS" "$RUN" <<'EOF'
"""The summary table: one row per stage, its state and what it found."""
import csv, json, os, sys

out, stages, steps, run = sys.argv[1], sys.argv[2].split(), int(sys.argv[3]), sys.argv[4]
state = os.path.join(out, "state")


def read(name):
    path = os.path.join(state, name)
    return open(path).read().strip() if os.path.exists(path) else None


def bench(report):
    parts = []
    for agent, result in report["agents"].items():
        rates = ", ".join(f"b{b.removeprefix('batch')} {t['samples_per_s']:.1f}/s" for b, t in result["train"].items())
        parts.append(f"{agent} {rates}")
    for agent, ratio in (report.get("ratio_to_reference") or {}).items():
        parts.append(f"{agent} x{ratio.get('train_batch1', float('nan')):.1f} the reference")
    return "; ".join(parts)


def cell():
    if os.path.exists(os.path.join(state, "cell.json")):
        result = json.loads(read("cell.json"))
        return f"step {steps}: mean score {result['mean_score']:.1f}, success {100 * result['success_rate']:.0f} % of {result['n_episodes']}"
    metrics = os.path.join(run, "metrics.csv")
    if os.path.exists(metrics):
        rows = list(csv.DictReader(open(metrics)))
        if rows:
            return f"trained to step {rows[-1]['step']} of {steps} (loss {float(rows[-1]['loss']):.3f}); run again to go on"
    return "not started"


rows = []
for stage in stages:
    status = "done" if os.path.exists(os.path.join(state, f"{stage}.done")) else "not done"
    if stage == "tests":
        found = read("tests.result") or "not run"
    elif stage == "bench":
        found = bench(json.loads(read("bench.json"))) if read("bench.json") else "not run"
    else:
        found = cell()
    rows.append((stage, status, found, os.path.join(out, "logs", f"{stage}.log")))
widths = [max(len(r[i]) for r in rows + [("stage", "status", "result", "log")]) for i in range(3)]
lines = ["  ".join(h.ljust(w) for h, w in zip(("stage", "status", "result"), widths)) + "  log"]
lines += ["  ".join(v.ljust(w) for v, w in zip(r[:3], widths)) + "  " + r[3] for r in rows]
text = "\n".join(lines)
print(text)
if os.path.isdir(out):  # not in a dry run
    with open(os.path.join(out, "summary.txt"), "w") as f:
        f.write(text + "\n")
sys.exit(0 if all(r[1] == "done" for r in rows) else 1)
EOF
status=$?
[ -n "$DRY" ] && status=0
exit $status
