#!/bin/bash
# One short GPU session (a lent machine holds ~15 minutes in all): the language lesson at its CUDA settings
# over three training seeds, the CPU settings given twice the CPU's steps over two seeds, and
# tests/agents/test_cuda_speed.py, side by side on one GPU. PyBullet is built there from a trimmed sdist
# (~65-85 s on 16 cores) while training runs: the demos are carried, and a complete demo folder needs no
# simulator; a job that reached evaluation before PyBullet was ready is rerun once (the quickstart resumes).
# Logs, results.json files and pictures (no checkpoints) come back as $OUT/results.tgz. SMOKE=1 runs tiny
# versions on a CPU to check the flags. Before the session, in the repository root:
#   echo /.whl/ >> .git/info/exclude; echo /.gpu/ >> .git/info/exclude; mkdir -p .whl
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
#   the lesson's 50 demos, full-size and half-size cameras, into .gpu/full/data and .gpu/half/data (what the
#   quickstart's --language would make: `cliport-demos --task put-one-block-in-bowl-seen-colors --n 50
#   --every-instruction --camera-scale S --data-dir .gpu/{full,half}/data` for S = 1.0 and 0.5)
# then run `bash scripts/gpu_session.sh` through the device tool with `.whl` and `.gpu` carried.
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=2
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
# TinyRenderer: the machine's EGL is untested and rendering is not what is measured here.
sed -i 's/^renderer = "auto"/renderer = "cpu"/' configs/env.toml
grep ^renderer configs/env.toml
$py -c "import torch; print(torch.__version__, torch.cuda.get_device_name(0) if torch.cuda.is_available() else 'no cuda')"
$py -c "import open_clip, gymnasium, matplotlib, tqdm; from torch.utils.tensorboard import SummaryWriter; print('imports ok')"
nproc

PB_DONE=/tmp/pybullet.done
if ! $py -c "import pybullet" 2>/dev/null; then
  (cd /tmp && tar xzf "$R/.whl/pybullet-3.2.7-trim.tar.gz" && cd pybullet-3.2.7 && \
   $py -m pip install --no-deps --no-build-isolation --no-index --target /tmp/site . >"$L/pybullet_build.log" 2>&1; \
   echo "exit $? at $(el)s" >>"$L/pybullet_build.log"; touch $PB_DONE) &
else
  touch $PB_DONE
fi

if [ -n "$SMOKE" ]; then
  S="--steps 3 --episodes 2 --swap-scenes 1"; SS="--steps 4 --episodes 2 --swap-scenes 1"; TL=400
  TINY="--width 0.125 --map-scale 0.5"
else
  S=""; SS="--steps 2400"; TL=$(( 470 - $(el) )); TINY=""
fi
# job NAME DEMOS ARGS...: the quickstart on carried demos; rerun once (it resumes) if it failed before PyBullet was ready.
job() {
  local name=$1 demos=$2; shift 2
  mkdir -p /tmp/$name && cp -r .gpu/$demos/data /tmp/$name/
  (
    timeout $TL $py scripts/quickstart.py --language --out /tmp/$name "$@" >"$L/$name.log" 2>&1
    rc=$?
    if [ $rc -ne 0 ] && [ $rc -ne 124 ]; then
      while [ ! -e $PB_DONE ]; do sleep 2; done
      echo "== rerun after rc $rc at $(el)s" >>"$L/$name.log"
      timeout $(( TL - $(el) )) $py scripts/quickstart.py --language --out /tmp/$name "$@" >>"$L/$name.log" 2>&1
      rc=$?
    fi
    echo "$name rc $rc at $(el)s" >>"$L/$name.log"
  ) &
}
echo "[$(el)s] jobs start, limit ${TL}s"
job cuda0 full --seed 0 $TINY $S
job cuda1 full --seed 1 $TINY $S
job cuda2 full --seed 2 $TINY $S
job cpuset0 half --seed 0 --width 0.125 --map-scale 0.5 --camera-scale 0.5 $SS
job cpuset1 half --seed 1 --width 0.125 --map-scale 0.5 --camera-scale 0.5 $SS
if [ -z "$SMOKE" ]; then
  (while [ ! -e $PB_DONE ]; do sleep 2; done
   timeout $(( TL - $(el) )) $py -m pytest -q -p no:cacheprovider tests/agents/test_cuda_speed.py -o addopts="" \
     >"$L/cuda_tests.log" 2>&1; echo "cuda tests rc $? at $(el)s" >>"$L/cuda_tests.log") &
fi
wait
echo "[$(el)s] jobs done"
tail -n 3 "$L/pybullet_build.log" 2>/dev/null
tail -n 30 "$L/cuda_tests.log" 2>/dev/null
for name in cuda0 cuda1 cuda2 cpuset0 cpuset1; do
  echo "== $name"; tr '\r' '\n' <"$L/$name.log" | grep -v "it/s\]$\|s/it\]$\|demo/s\]$\|ep/s\]$\|s/ep\]$" | tail -n 8
  $py -c "import json,sys; r=json.load(open(sys.argv[1])); print(json.dumps({k: r.get(k) for k in ('device','solved','instruction_following','seconds','training')})[:900])" \
    /tmp/$name/results.json 2>/dev/null | sed 's/"swaps": \[[^]]*\]//'
done
tar czf "$OUT/results.tgz" --exclude='*.safetensors' --exclude='*.pt' --exclude='checkpoints' --exclude=data \
  --exclude="*.npz" --exclude='tensorboard' $L /tmp/cuda0 /tmp/cuda1 /tmp/cuda2 /tmp/cpuset0 /tmp/cpuset1 2>/dev/null
ls -la "$OUT"
echo "[$(el)s] end"
