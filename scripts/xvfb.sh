#!/usr/bin/env bash
# Runs a command on a private, headless X server: `scripts/xvfb.sh build/haze view ...`. The server picks a
# free display itself (-displayfd), so parallel runs (ctest -j) never race for one; it is stopped when the
# command ends, and the command's exit status is this script's.
set -euo pipefail
tmp=$(mktemp -d)
Xvfb -displayfd 3 -screen 0 1920x1080x24 -nolisten tcp 3>"$tmp/display" 2>"$tmp/xvfb.log" &
xvfb=$!
cleanup() {
  kill "$xvfb" 2>/dev/null || true
  wait "$xvfb" 2>/dev/null || true
  rm -rf "$tmp"
}
trap cleanup EXIT
for _ in $(seq 200); do
  [ -s "$tmp/display" ] && break
  if ! kill -0 "$xvfb" 2>/dev/null; then
    echo "xvfb.sh: Xvfb did not start: $(tail -n 3 "$tmp/xvfb.log")" >&2
    exit 1
  fi
  sleep 0.05
done
if [ ! -s "$tmp/display" ]; then
  echo "xvfb.sh: Xvfb gave no display number within 10 s" >&2
  exit 1
fi
export DISPLAY=":$(head -n 1 "$tmp/display")"
set +e
# The command runs as a child so that a TERM or INT (timeout, Ctrl-C) reaches it too before the server goes.
"$@" &
child=$!
trap 'kill -TERM "$child" 2>/dev/null' TERM INT
wait "$child"
status=$?
while kill -0 "$child" 2>/dev/null; do
  wait "$child"
  status=$?
done
exit $status
