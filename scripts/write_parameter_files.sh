#!/usr/bin/env bash
# Writes config/pipeline.yaml and cfg/*.cfg from the parameter table
# (include/endo_guidance/io/parameter_table.h), after a build. The test
# YamlConfig.ParameterFilesMatchTheTable fails until they are written.
set -euo pipefail
cd "$(dirname "$0")/.."
bin=build/devel/lib/endo_guidance/endo_guidance_params
[ -x "$bin" ] || { echo "write_parameter_files.sh: build first (cmake --build build --target endo_guidance_params)" >&2; exit 2; }
"$bin" --yaml > config/pipeline.yaml
for node in Segmentation InsertionPoints; do "$bin" --cfg "$node" > "cfg/$node.cfg"; done
echo "written: config/pipeline.yaml cfg/Segmentation.cfg cfg/InsertionPoints.cfg"
