#!/bin/sh
# `ros2 run bptsb_ros @NODE@` entry point, installed to <prefix>/lib/bptsb_ros/@NODE@ by `pip install`.
# It runs the console script that pip wrote to <prefix>/bin/@NODE@, whose shebang names the right Python.
here=$(CDPATH= cd -- "$(dirname -- "$0")" && pwd -P) || exit 1
exec "$here/../../bin/@NODE@" "$@"
