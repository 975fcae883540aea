#!/usr/bin/env bash
# Fuzzes every harness of test/fuzz with libFuzzer (clang, ASan + UBSan) for SECONDS each
# (default 600), after replaying its seeds and its regression inputs. Builds build/fuzz first.
#   scripts/fuzz.sh [SECONDS] [HARNESS...]     e.g. scripts/fuzz.sh 15 geometry
#   scripts/fuzz.sh build                       only build them (scripts/test.sh does)
# The growing corpus stays in build/fuzz/corpus/<harness>; a crash is saved in
# build/fuzz/crashes/ and fails the script (make it a regression: copy it into
# test/fuzz/regressions/<harness>/ with the fix). Summary: build/fuzz/summary.txt.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-600}"
shift || true
harnesses=("$@")
[ ${#harnesses[@]} -eq 0 ] && harnesses=(geometry pipeline config readers)
[[ "$seconds" =~ ^[0-9]+$ || "$seconds" = build ]] || { echo "fuzz.sh: SECONDS must be a whole number, not '$seconds'" >&2; exit 2; }
command -v clang++ >/dev/null || { echo "fuzz.sh: clang++ not found (Debian: apt install clang)" >&2; exit 2; }

B=build/fuzz
if [ ! -f "$B/CMakeCache.txt" ]; then
  mkdir -p "$B"
  cmake -S . -B "$B" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_COMPILER=clang++ -DENDO_GUIDANCE_FUZZ=ON \
    -DCATKIN_ENABLE_TESTING=OFF -DPYTHON_EXECUTABLE=/usr/bin/python3 >"$B/configure.log" 2>&1 \
    || { cat "$B/configure.log"; exit 1; }
fi
built=0  # (the build's own status, not grep's)
cmake --build "$B" -j"$(nproc)" --target fuzzers -- --no-print-directory >"$B/build.log" 2>&1 || built=$?
grep -vE '^\[ *[0-9]+%\] (Built target|Generating|Building)|^Scanning' "$B/build.log" || true
[ "$built" -eq 0 ] || { echo "fuzz.sh: the harnesses did not build ($B/build.log)" >&2; exit "$built"; }
[ "$seconds" = build ] && exit 0

export ASAN_OPTIONS="detect_leaks=0:abort_on_error=1:symbolize=1"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
mkdir -p "$B/crashes"
status=0
: >"$B/summary.txt"
for h in "${harnesses[@]}"; do
  exe="$B/devel/lib/endo_guidance/fuzz_$h"
  [ -x "$exe" ] || exe="$(find "$B" -name "fuzz_$h" -type f -perm -u+x | head -1)"
  [ -x "$exe" ] || { echo "fuzz.sh: no harness fuzz_$h" >&2; exit 2; }
  seeds="test/fuzz/corpus/$h"
  work="$B/corpus/$h"
  mkdir -p "$work"
  case "$h" in readers) maxlen=65536 ;; pipeline) maxlen=8192 ;; *) maxlen=4096 ;; esac
  common=(-timeout=20 -rss_limit_mb=4096 -max_len="$maxlen" -artifact_prefix="$B/crashes/$h-" -print_final_stats=1)
  log="$B/$h.log"
  # The regression inputs (past crashes), one by one, then seeds + corpus and new inputs.
  regressions=()
  [ -d "test/fuzz/regressions/$h" ] && mapfile -t regressions < <(find "test/fuzz/regressions/$h" -type f | sort)
  if [ ${#regressions[@]} -gt 0 ] && ! "$exe" "${common[@]}" "${regressions[@]}" >"$log.regressions" 2>&1; then
    echo "fuzz.sh: $h: a regression input crashes again (see $log.regressions)" >&2
    status=1
  fi
  extra=()
  if [ "$h" = readers ]; then  # video seeds are written here, not kept in the repository
    [ -d "$B/seeds/readers" ] || /usr/bin/python3 test/fuzz/make_corpus.py --videos "$B/seeds/readers"
    extra=("$B/seeds/readers")
  fi
  if "$exe" "${common[@]}" -max_total_time="$seconds" "$work" "$seeds" "${extra[@]}" >"$log" 2>&1; then result=ok; else result=CRASH; status=1; fi
  runs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' || echo 0)
  cov=$(grep -oE 'cov: [0-9]+' "$log" | tail -1 | grep -oE '[0-9]+' || echo 0)
  line=$(printf '%-9s %s  %6s s  %9s runs  cov %5s  corpus %4s  regressions %d' "$h" "$result" "$seconds" "$runs" "$cov" \
    "$(find "$work" -type f | wc -l)" "${#regressions[@]}")
  echo "$line" | tee -a "$B/summary.txt"
  [ "$result" = ok ] || { grep -m1 -A25 -E 'ERROR: (AddressSanitizer|libFuzzer)|runtime error|invariant broken' "$log" >&2 || tail -30 "$log" >&2; }
done
exit $status
