#!/bin/bash
# One short GPU session, as run on the first lent H200: install the packages the GPU machine lacks from
# carried wheels, build PyBullet there from a trimmed sdist (~65-85 s on 16 cores), then at the published size:
# scripts/bench_model.py (BENCH=1), a block-insertion recipe study (cliport vs ravens, 1000 steps), the language
# quickstart at its CUDA settings (600 and 1200 steps) and tests/agents/test_cuda_speed.py, side by side.
# Logs and results (no checkpoints) come back as $OUT/results.tgz. SMOKE=1 runs tiny versions on a CPU to
# check the flags. Before the session, in the repository root (Python 3.12 wheels for an x86-64 machine):
#   echo /.whl/ >> .git/info/exclude; mkdir -p .whl
#   pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#     --platform manylinux2014_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux_2_28_x86_64 -d .whl \
#     open_clip_torch ftfy wcwidth regex gymnasium cloudpickle farama-notifications tensorboard \
#     tensorboard-data-server absl-py markdown werkzeug tqdm matplotlib contourpy cycler fonttools kiwisolver \
#     pyparsing python-dateutil six markupsafe protobuf pytest pluggy iniconfig packaging pytest-timeout \
#     setuptools wheel
#   pip download --no-deps --no-binary=:all: pybullet==3.2.7 -d /tmp   # 80 MB: drop its bundled data
#   (cd /tmp && tar xzf pybullet-3.2.7.tar.gz && cd pybullet-3.2.7 && rm -rf examples/pybullet/gym/pybullet_envs \
#     && find examples/pybullet/gym/pybullet_data -mindepth 1 ! -name __init__.py -delete \
#     && cd .. && tar czf "$OLDPWD/.whl/pybullet-3.2.7-trim.tar.gz" pybullet-3.2.7)
# then run `bash scripts/gpu_session.sh` through the device tool with `.whl` carried.
export PYTHONUNBUFFERED=1
cd "$(dirname "$0")/.."
R=$PWD
OUT=${OUT:-/tmp/out}
L=/tmp/logs
mkdir -p "$OUT" /tmp/site $L
T0=$(date +%s)
el() { echo $(( $(date +%s) - T0 )); }
py=python3
W=""
for pair in open_clip:open_clip_torch ftfy:ftfy wcwidth:wcwidth regex:regex gymnasium:gymnasium cloudpickle:cloudpickle \
  farama_notifications:farama_notifications tensorboard:tensorboard tensorboard_data_server:tensorboard_data_server \
  absl:absl_py markdown:markdown werkzeug:werkzeug tqdm:tqdm matplotlib:matplotlib contourpy:contourpy cycler:cycler \
  fontTools:fonttools kiwisolver:kiwisolver pyparsing:pyparsing dateutil:python_dateutil six:six markupsafe:markupsafe \
  google.protobuf:protobuf pytest:pytest pluggy:pluggy iniconfig:iniconfig packaging:packaging pytest_timeout:pytest_timeout \
  setuptools:setuptools wheel:wheel; do
  mod=${pair%%:*}; whl=${pair##*:}
  $py -c "import $mod" 2>/dev/null || W="$W $(ls .whl/${whl}-*.whl)"
done
echo "[$(el)s] installing:$W"
[ -n "$W" ] && $py -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site $W
export PYTHONPATH=$R:/tmp/site
$py -c "import torch; print(torch.__version__, torch.cuda.get_device_name(0) if torch.cuda.is_available() else 'no cuda')"
$py -c "import open_clip, gymnasium, matplotlib, tqdm; from torch.utils.tensorboard import SummaryWriter; print('imports ok')"
nproc

if ! $py -c "import pybullet" 2>/dev/null; then
  (cd /tmp && tar xzf "$R/.whl/pybullet-3.2.7-trim.tar.gz" && cd pybullet-3.2.7 && \
   $py -m pip install --no-deps --no-build-isolation --no-index --target /tmp/site . >"$L/pybullet_build.log" 2>&1; \
   echo "exit $? at $(el)s" >>"$L/pybullet_build.log") &
  PB=$!
fi

if [ -n "$BENCH" ]; then
  for a in transporter_only two_stream; do
    echo "[$(el)s] bench $a"
    timeout 60 $py scripts/bench_model.py --device cuda --agent $a --act-batch 8 >"$L/bench_$a.json" 2>"$L/bench_$a.err"
    echo "[$(el)s] bench $a rc $?"; tail -n 3 "$L/bench_$a.err"; head -c 2500 "$L/bench_$a.json"; echo
  done
fi
[ -n "$PB" ] && wait $PB
tail -n 3 "$L/pybullet_build.log" 2>/dev/null
$py -c "import pybullet; print('pybullet ok')" || echo "PYBULLET FAILED"

if [ -n "$SMOKE" ]; then
  RP="--n-steps 2 --checkpoint-steps 1 2 --test-episodes 2 --eval-workers 2 --width 0.125 --camera-scale 0.5 --n-rotations 4"
  L1="--steps 2 --episodes 2 --swap-scenes 2 --demos 2"; L2="--steps 3 --episodes 2 --swap-scenes 2 --demos 2"; TL=300
else
  RP="--n-steps 1000 --checkpoint-steps 500 1000 --test-episodes 20 --eval-workers 5"
  L1=""; L2="--steps 1200"; TL=$(( 440 - $(el) ))
fi
echo "[$(el)s] jobs start, limit ${TL}s"
(timeout $TL $py -c "from cliport.cli.reproduce import entry; entry()" --task block-insertion --agents transporter_only --n-demos 10 --seeds 0 \
   --recipes cliport ravens --val-episodes 0 --batch-size 1 --demo-workers 6 $RP \
   --data-dir /tmp/data --out /tmp/bi --no-progress >"$L/bi.log" 2>&1; echo "bi rc $? at $(el)s" >>"$L/bi.log") &
(timeout $TL $py scripts/quickstart.py --language --out /tmp/lang1 $L1 >"$L/lang1.log" 2>&1; echo "lang1 rc $? at $(el)s" >>"$L/lang1.log") &
(timeout $TL $py scripts/quickstart.py --language --out /tmp/lang2 $L2 >"$L/lang2.log" 2>&1; echo "lang2 rc $? at $(el)s" >>"$L/lang2.log") &
[ -z "$SMOKE" ] && (timeout $TL $py -m pytest -q -p no:cacheprovider tests/agents/test_cuda_speed.py -o addopts="" >"$L/cuda_tests.log" 2>&1; echo "cuda tests rc $? at $(el)s" >>"$L/cuda_tests.log") &
wait
echo "[$(el)s] jobs done"; tail -n 40 "$L/cuda_tests.log"; tail -n 3 $L/bi.log $L/lang1.log $L/lang2.log
tar czf "$OUT/results.tgz" --exclude='*.safetensors' --exclude='*.pt' --exclude='checkpoints' --exclude=demos --exclude="*.npz" \
  --exclude='tensorboard' --exclude='*.gif' $L /tmp/bi /tmp/lang1 /tmp/lang2 2>/dev/null
cp /tmp/lang1/*.gif "$OUT/" 2>/dev/null
ls -la "$OUT"
echo "[$(el)s] end"
