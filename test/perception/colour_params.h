// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The colour method's own tests run it by name: the default detector is the learned one.
#pragma once

#include "endo_guidance/perception/segmentation_params.h"
#include "endo_guidance/pipeline/pipeline.h"

namespace endo_guidance::test {

inline perception::SegmentationParams colourParams() {
  perception::SegmentationParams p;
  p.detector = perception::SegmentationParams::Detector::kColour;
  return p;
}
inline pipeline::PipelineParams colourPipelineParams() {
  pipeline::PipelineParams p;
  p.segmentation = colourParams();
  return p;
}

}  // namespace endo_guidance::test
