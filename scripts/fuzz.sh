#!/usr/bin/env bash
# A long fuzz campaign: the suite's fuzz_test with many cases, one seed after another, without the validation
# layer (faster). Usage: scripts/fuzz.sh [CASES_PER_SEED] [SEEDS...]; prints the counts of each seed.
set -uo pipefail
cd "$(dirname "$0")/.."
cases=${1:-500}
shift || true
seeds=("$@")
[ ${#seeds[@]} -eq 0 ] && seeds=(11 12 13 14)
export HAZE_VALIDATION=0
export HAZE_SHADER_CACHE=${HAZE_SHADER_CACHE:-$PWD/build/shader-cache}
export MESA_SHADER_CACHE_DIR=${MESA_SHADER_CACHE_DIR:-$PWD/build/mesa-cache}
status=0
for seed in "${seeds[@]}"; do
  HAZE_FUZZ_CASES=$cases HAZE_FUZZ_SEED=$seed build/haze_tests --gtest_filter='Fuzz.*' --gtest_brief=1 | grep -E "^fuzz seed|Failure|case [0-9]+" || true
  [ "${PIPESTATUS[0]}" -eq 0 ] || status=1
done
exit $status
