#!/bin/bash
# Precise shared tables measurement (README "Performance"): per case a cold CLI call on an empty table cache
# (build + save) and a second call (table loaded), with user CPU from /usr/bin/time and per-order
# stage times in $OUT/c-*/cold.log (SKYBAKE_LOG=skybake=debug). Needs python3 for the wavelength lists.
B=${SKYBAKE_BIN:-target/release/skybake}
OUT=${OUT:-/tmp/skybake-precise-cli}
# skybake refuses unknown SKYBAKE_* variables: do not pass ours on.
unset SKYBAKE_BIN
wl() { python3 -c "
n=$1
if n==1: print('550')
else:
    a,b=(380.0,755.0) if n<=16 else ((370.0,830.0) if n<=47 else (360.0,826.2))
    print(','.join('%.2f'%(a+(b-a)*i/(n-1)) for i in range(n)))"; }
for c in "earth standard 16" "earth standard 47" "earth-hazy standard 16" "earth standard 1" "earth standard 64" "earth draft 16" "earth high 16"; do
  set -- $c
  d=$OUT/c-$1-$2-$3; rm -rf $d; mkdir -p $d
  W=$(wl $3)
  for call in cold second; do
    SKYBAKE_CACHE_DIR=$d/cache SKYBAKE_LOG=skybake=debug /usr/bin/time -f "TIME $c $call wall %e user %U sys %S" $B sky --atmosphere $1 --quality $2 --wavelengths $W --sun-elevation-deg 20 -o $d/$call.exr > /dev/null 2> $d/$call.log
    tail -1 $d/$call.log; echo "LOAD $(cut -d' ' -f1-3 /proc/loadavg)"
  done
done
