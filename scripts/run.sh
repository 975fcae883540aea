#!/usr/bin/env bash
# The main job: set up (apt packages, configure, build; quick when nothing changed), then run the
# geometric core on the built-in synthetic surgery and print estimated vs true insertion points.
# Extra arguments go to endo_guidance_synthetic (see --help).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec build/devel/lib/endo_guidance/endo_guidance_synthetic "$@"
