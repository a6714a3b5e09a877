#!/usr/bin/env bash
# Make a folder that installs cliport on a Linux machine without network (a cluster's GPU node, say) with Python 3.11
# or 3.12: the wheels of every dependency for each Python asked for, cliport's own wheel, and the PyBullet source
# (PyBullet ships no wheels for these Pythons; it is compiled on the machine, which needs a C++ compiler, g++).
# Run it where there is network, from the checkout; copy the folder over; install with its INSTALL.txt.
#
# Usage: bash scripts/offline_bundle.sh [--out DIR] [--python-version V ...] [--extras LIST] [--arch ARCH]
#                                       [--pybullet VERSION] [--index-url URL] [--extra-index-url URL]
#                                       [--python PY] [--dry-run]
#   --out DIR             the bundle (default ./cliport-offline-bundle); made if missing, added to if present
#   --python-version V    3.11 or 3.12, repeatable (default both: torch's wheel is per version, the rest is shared)
#   --extras LIST         cliport's extras to include, comma-separated (default dev: tests, gpu_check; "" for none)
#   --arch ARCH           x86_64 (default) or aarch64
#   --pybullet VERSION    the PyBullet source release (default 3.2.7)
#   --index-url URL, --extra-index-url URL
#                         passed to pip download (e.g. PyTorch's index for another CUDA build of torch)
#   --python PY           the Python whose pip downloads (default: $PY, else the checkout's .venv, else python3)
#   --dry-run             print the requirements and the commands, download nothing
# The folder then holds wheels/ (every wheel, for each Python), pybullet-VERSION.tar.gz, requirements.txt and
# INSTALL.txt. Expect a few GB: torch with its CUDA libraries is most of it.
set -uo pipefail

usage() { sed -n '2,/^$/p' "$0" | sed 's/^# \{0,1\}//'; }
fail() { echo "error: offline_bundle.sh: $1" >&2; exit 2; }

ROOT=$(cd "$(dirname "$0")/.." && pwd)
OUT=./cliport-offline-bundle
VERSIONS=()
EXTRAS=dev
ARCH=x86_64
PYBULLET=3.2.7
INDEX=()
PY=${PY:-}
DRY=""
while [ $# -gt 0 ]; do
  case $1 in
    -h|--help) usage; exit 0 ;;
    --out|--python-version|--extras|--arch|--pybullet|--index-url|--extra-index-url|--python)
      [ $# -ge 2 ] || fail "$1 needs a value (see --help)"
      case $1 in
        --out) OUT=$2 ;; --python-version) VERSIONS+=("$2") ;; --extras) EXTRAS=$2 ;; --arch) ARCH=$2 ;;
        --pybullet) PYBULLET=$2 ;; --index-url|--extra-index-url) INDEX+=("$1" "$2") ;; --python) PY=$2 ;;
      esac
      shift 2 ;;
    --dry-run) DRY=1; shift ;;
    *) fail "unknown option $1 (see --help)" ;;
  esac
done
[ ${#VERSIONS[@]} -gt 0 ] || VERSIONS=(3.11 3.12)
for v in "${VERSIONS[@]}"; do
  case $v in 3.11|3.12) ;; *) fail "--python-version must be 3.11 or 3.12, got $v" ;; esac
done
case $ARCH in x86_64|aarch64) ;; *) fail "--arch must be x86_64 or aarch64, got $ARCH" ;; esac
[[ $PYBULLET =~ ^[0-9]+(\.[0-9]+)*$ ]] || fail "--pybullet must be a version such as 3.2.7, got $PYBULLET"
[ -n "$OUT" ] || fail "--out needs a folder"
if [ -z "$PY" ]; then
  if [ -x "$ROOT/.venv/bin/python" ]; then PY=$ROOT/.venv/bin/python; else PY=python3; fi
fi
command -v "$PY" >/dev/null 2>&1 || fail "no Python at $PY: pass --python"

# The requirements: pyproject.toml's dependencies and the extras asked for, without PyBullet (its source comes
# apart), and the build tools that compile it and install cliport.
REQUIREMENTS=$("$PY" - "$ROOT/pyproject.toml" "$EXTRAS" <<'EOF'
import re, sys, tomllib

project = tomllib.load(open(sys.argv[1], "rb"))["project"]
extras = [e for e in sys.argv[2].split(",") if e]
unknown = [e for e in extras if e not in project.get("optional-dependencies", {})]
if unknown:
    sys.exit(f"error: offline_bundle.sh: unknown extra(s) {', '.join(unknown)} (pyproject.toml has "
             f"{', '.join(project.get('optional-dependencies', {}))})")
requirements = list(project["dependencies"]) + [r for e in extras for r in project["optional-dependencies"][e]]
names = set()
for requirement in requirements + ["setuptools>=68", "wheel"]:
    name = re.split(r"[<>=!~\[; ]", requirement, maxsplit=1)[0].lower()
    if name != "pybullet" and name not in names:
        names.add(name)
        print(requirement)
EOF
) || exit 2
PLATFORMS=()
for tag in manylinux_2_28 manylinux_2_17 manylinux2014 manylinux_2_12 manylinux2010 manylinux_2_5 manylinux1; do
  PLATFORMS+=(--platform "${tag}_${ARCH}")
done

echo "offline bundle for Python ${VERSIONS[*]} on Linux $ARCH in $OUT"
echo "requirements:"; echo "$REQUIREMENTS" | sed 's/^/  /'
step() {
  if [ -n "$DRY" ]; then echo "would run: $*"; return 0; fi
  echo "running: $*"
  "$@"
}
if [ -z "$DRY" ]; then
  mkdir -p "$OUT/wheels" || fail "cannot make $OUT"
  OUT=$(cd "$OUT" && pwd)
  echo "$REQUIREMENTS" >"$OUT/requirements.txt"
fi
REQ_FILE=$OUT/requirements.txt
status=0
for v in "${VERSIONS[@]}"; do
  step "$PY" -m pip download --only-binary=:all: --implementation cp --python-version "$v" "${PLATFORMS[@]}" \
    "${INDEX[@]}" -d "$OUT/wheels" -r "$REQ_FILE" || { echo "pip download for Python $v failed" >&2; status=1; }
done
step "$PY" -m pip wheel --no-deps -w "$OUT/wheels" "$ROOT" || status=1
step "$PY" -m pip download --no-deps --no-binary=:all: "${INDEX[@]}" -d "$OUT" "pybullet==$PYBULLET" || status=1

INSTALL="Installing cliport from this folder (BUNDLE) on a machine without network, Python ${VERSIONS[*]}:

  python3 -m venv .venv
  .venv/bin/pip install --no-index --find-links BUNDLE/wheels setuptools wheel
  .venv/bin/pip install --no-index --find-links BUNDLE/wheels --no-build-isolation BUNDLE/pybullet-$PYBULLET.tar.gz
  .venv/bin/pip install --no-index --find-links BUNDLE/wheels cliport${EXTRAS:+[$EXTRAS]}

PyBullet compiles from its source (a minute or two on 16 cores; it needs g++). In a cliport checkout, install it
editable instead of the last line (the tests and scripts/gpu_check.sh need the checkout):

  .venv/bin/pip install --no-index --find-links BUNDLE/wheels --no-build-isolation -e \".${EXTRAS:+[$EXTRAS]}\"
"
if [ -z "$DRY" ]; then
  echo "$INSTALL" >"$OUT/INSTALL.txt"
  du -sh "$OUT" 2>/dev/null
else
  echo "$INSTALL"
fi
[ $status -eq 0 ] || echo "error: offline_bundle.sh: some downloads failed (see above); the bundle is incomplete" >&2
exit $status
