#!/usr/bin/env bash
# The suite under load, as a new user meets it: clone this repository (its committed HEAD) into a
# temporary folder and run `make test` there N times in a row, with two CPU-bound processes
# running beside it the whole time. Prints one line per run, then "N passed, M failed" and the
# load average. Exit status 0 only when every run passed.
#
#   scripts/stress_suite.sh [-n RUNS] [--venv DIR] [--keep]
#
#   -n RUNS     how many times to run `make test` (default 10)
#   --venv DIR  use this existing environment instead of the clone's own .venv (which `make`
#               would create and install first: minutes, and torch's wheels); the clone's
#               sources still come first on the path (PYTHONPATH=clone/src), and the
#               environment is never modified (make is told its install stamp is up to date)
#   --keep      keep the clone and the logs (default: removed unless a run failed)
set -euo pipefail

runs=10
venv=""
keep=0
while [ $# -gt 0 ]; do
  case "$1" in
    -n) runs="$2"; shift 2 ;;
    --venv) venv="$(cd "$2" && pwd)"; shift 2 ;;
    --keep) keep=1; shift ;;
    -h|--help) sed -n '2,17p' "$0"; exit 0 ;;
    *) echo "stress_suite.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done
case "$runs" in ''|*[!0-9]*|0) echo "stress_suite.sh: -n needs a positive integer" >&2; exit 2 ;; esac

repo="$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
work="$(mktemp -d "${TMPDIR:-/tmp}/rapidds-stress.XXXXXX")"
clone="$work/rapidds"
git clone --quiet --no-hardlinks "$repo" "$clone"
echo "clone of $(git -C "$clone" rev-parse --short HEAD) ($(git -C "$repo" rev-parse --abbrev-ref HEAD)) in $clone"

make_args=()
if [ -n "$venv" ]; then
  # BIN points make at the given environment; -o marks its install stamp as up to date so make
  # never reinstalls into it.
  make_args=(VENV="$venv" -o "$venv/.installed")
  export PYTHONPATH="$clone/src"
fi

busy=()
cleanup() {
  for pid in "${busy[@]}"; do kill "$pid" 2>/dev/null || true; done
  wait "${busy[@]}" 2>/dev/null || true
}
trap cleanup EXIT
for _ in 1 2; do
  python3 -c "while True: pass" &
  busy+=("$!")
done
echo "two CPU-bound processes beside the suite: ${busy[*]}"

passed=0
failed=0
for i in $(seq 1 "$runs"); do
  log="$work/run-$i.log"
  start=$(date +%s)
  if make --no-print-directory -C "$clone" "${make_args[@]}" test >"$log" 2>&1; then
    passed=$((passed + 1)); verdict=passed
  else
    failed=$((failed + 1)); verdict="FAILED (log: $log)"
  fi
  summary=$(grep -E "[0-9]+ (passed|failed|error)" "$log" | tail -n 1 || tail -n 1 "$log")
  echo "run $i/$runs: $verdict in $(( $(date +%s) - start )) s ($summary)," \
       "load $(cut -d' ' -f1-3 /proc/loadavg)"
done

echo "$passed passed, $failed failed"
echo "load average (1, 5, 15 min): $(cut -d' ' -f1-3 /proc/loadavg); $(nproc) CPUs"
if [ "$failed" -eq 0 ] && [ "$keep" -eq 0 ]; then
  rm -rf "$work"
else
  echo "kept $work"
fi
[ "$failed" -eq 0 ]
