#!/usr/bin/env bash
# Load test of the skybake service on loopback with wrk and curl (Debian: apt-get install wrk curl).
#
#   tools/load_test.sh [DURATION_S]        # default 10 s per scenario
#
# Scenarios (each bounded by DURATION_S, 2 wrk threads, 32 connections):
#   1. cached-small : GET /v1/sky, small table (17×16, 3 wavelengths), JSON  — cache hits, at 8 and
#                     at 32 connections
#   2. cached-exr   : GET /v1/sky, default table (129×64, 16 wavelengths), EXR — cache hits, large bodies
#   3. miss-mix     : GET /v1/sky, 90 % the cached small request, 10 % a new sun elevation each
#                     (cold misses: fast method, draft quality, computed and cached)
# The server binary is $SKYBAKE_BIN (default target/release/skybake if present, else
# target/debug/skybake; the dev profile is optimised, opt-level 2). Output: wrk's summary and
# latency distribution per scenario, and the server's computation count.
set -euo pipefail

DURATION="${1:-10}"
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BIN="${SKYBAKE_BIN:-}"
if [[ -z "$BIN" ]]; then
  if [[ -x "$ROOT/target/release/skybake" ]]; then BIN="$ROOT/target/release/skybake"; else BIN="$ROOT/target/debug/skybake"; fi
fi
for tool in wrk curl; do
  command -v "$tool" >/dev/null || { echo "$tool not found (apt-get install $tool)" >&2; exit 1; }
done
[[ -x "$BIN" ]] || { echo "no binary at $BIN (cargo build)" >&2; exit 1; }

WORK="$(mktemp -d)"
PORT="${SKYBAKE_LOAD_PORT:-18080}"
ADDR="127.0.0.1:$PORT"
cleanup() { [[ -n "${PID:-}" ]] && kill -TERM "$PID" 2>/dev/null && wait "$PID" 2>/dev/null; rm -rf "$WORK"; }
trap cleanup EXIT

SKYBAKE_CONCURRENCY_LIMIT=4096 "$BIN" serve --bind "$ADDR" --cache-dir "$WORK/cache" 2>"$WORK/server.log" &
PID=$!
for _ in $(seq 100); do "$BIN" healthcheck --addr "$ADDR" 2>/dev/null && break; sleep 0.1; done

SMALL="/v1/sky?method=fast&quality=draft&wavelengths=440,550,680&elevation_count=17&azimuth_count=16&sun_elevation_deg=20"
DEFAULT_EXR="/v1/sky?method=fast&sun_elevation_deg=20&format=exr"

warm() { # one request fills the cache (the first may compute for a while)
  curl -sf -o /dev/null --max-time 120 "http://$ADDR$1"
}

echo "== binary: $BIN; cores: $(nproc); duration: ${DURATION}s per scenario"
warm "$SMALL"
for c in 8 32; do
  echo "== 1. cached-small, $c connections: GET $SMALL"
  wrk -t2 -c"$c" -d"${DURATION}s" --latency "http://$ADDR$SMALL"
done

warm "$DEFAULT_EXR"
echo "== 2. cached-exr: GET $DEFAULT_EXR"
wrk -t2 -c32 -d"${DURATION}s" --latency "http://$ADDR$DEFAULT_EXR"

cat >"$WORK/mix.lua" <<LUA
local threads = 0
setup = function(thread)
  thread:set("tid", threads)
  threads = threads + 1
end
local n = 0
request = function()
  n = n + 1
  if n % 10 == 0 then
    -- a new product: a sun elevation not asked before (each thread walks its own range)
    local e = string.format("%.4f", -17 + tid * 50 + (n / 10) * 0.0011)
    return wrk.format("GET", "/v1/sky?method=fast&quality=draft&wavelengths=440,550,680&elevation_count=17&azimuth_count=16&sun_elevation_deg=" .. e)
  end
  return wrk.format("GET", "$SMALL")
end
LUA
echo "== 3. miss-mix (10 % cold misses): $SMALL + new sun elevations"
wrk -t2 -c32 -d"${DURATION}s" --latency -s "$WORK/mix.lua" "http://$ADDR"

echo "== server counters"
curl -sf "http://$ADDR/metrics" |
  grep -E '^skybake_(computations_total|load_shed_total|request_timeouts_total|response_cache_hits_total|cache_hits_total|cache_misses_total|single_flight_joins_total)' || true
