#!/usr/bin/env bash
# Makes sure the tools to build and run the firmware exist (placeholder: filled by the firmware
# issue). Prints which toolchain will be used.
set -euo pipefail
exit 0
