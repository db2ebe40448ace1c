#!/usr/bin/env bash
# Builds `lkh_solve`: LKH-3 (the copy of LKH-3.0.8 that the elkai package ships in its
# source distribution on PyPI) behind a small command line of ours, so the tsp benchmark can
# set LKH's own parameters (elkai's Python API sets only RUNS, and LKH's default of one
# trial per point takes hours on 20 000 points). Benchmark only: never a doodlecam dependency.
#
#   bash benchmarks/lkh/build.sh /tmp/lkh        # then: bench_styles.py --lkh /tmp/lkh/lkh_solve
set -euo pipefail
here=$(dirname "$(realpath "$0")")
out=$(realpath -m "${1:-/tmp/lkh}")
mkdir -p "$out" && cd "$out"
version=2.0.1
if [ ! -d "elkai-$version" ]; then
  url=$(curl -sSL https://pypi.org/simple/elkai/ | grep -o "https://[^\"#]*elkai-$version.tar.gz" | head -1)
  curl -sSL "$url" | tar xz
fi
src="$out/elkai-$version/LKH-3.0.8/SRC"
mkdir -p "$src/OBJ"
make -s -C "$out/elkai-$version/LKH-3.0.8" >/dev/null 2>&1 || make -C "$out/elkai-$version/LKH-3.0.8" >/dev/null
# elkai's LKHmain.c holds the solver's entry point and a self-test main(): keep the first
gcc -O3 -c -I"$src/INCLUDE" -Dmain=elkai_selftest_main "$src/LKHmain.c" -o LKHmain.o
gcc -O3 -I"$src/INCLUDE" "$here/lkh_solve.c" LKHmain.o $(ls "$src"/OBJ/*.o | grep -v /LKHmain.o) -lm -o lkh_solve
echo "$out/lkh_solve"
