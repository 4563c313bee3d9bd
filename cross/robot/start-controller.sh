#!/bin/sh
# Starts the dribble controller on the robot with the arguments in
# /etc/default/dribble-controller (DRIBBLE_ARGS), or a one-minute timing check of the loop.
here="$(cd "$(dirname "$0")" && pwd)"
[ -f /etc/default/dribble-controller ] && . /etc/default/dribble-controller
# shellcheck disable=SC2086
exec "$here/bin/dribble-controller" ${DRIBBLE_ARGS:-dry-run --seconds 60 --fifo-priority 40}
