// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// Prints the files the parameter table gives (io/parameter_table.h): config/pipeline.yaml
// (--yaml) and a node's dynamic_reconfigure .cfg (--cfg Segmentation | InsertionPoints).
// scripts/write_parameter_files.sh writes them into the package.
#include <cstring>
#include <iostream>

#include "endo_guidance/io/parameter_table.h"

int main(int argc, char** argv) {
  using endo_guidance::io::Live;
  if (argc == 2 && std::strcmp(argv[1], "--yaml") == 0) {
    std::cout << endo_guidance::io::pipelineYaml();
    return 0;
  }
  if (argc == 3 && std::strcmp(argv[1], "--cfg") == 0) {
    if (std::strcmp(argv[2], "Segmentation") == 0) return std::cout << endo_guidance::io::reconfigureCfg(Live::kSegmentation), 0;
    if (std::strcmp(argv[2], "InsertionPoints") == 0)
      return std::cout << endo_guidance::io::reconfigureCfg(Live::kInsertionPoints), 0;
  }
  std::cerr << "usage: endo_guidance_params --yaml | --cfg Segmentation|InsertionPoints\n";
  return 2;
}
