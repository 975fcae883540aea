// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The package's own model (TF.js, @tensorflow/tfjs 4.22.0, CPU) on a fixed image: the stored
// values that scripts/pretrained_backbone.py check compares the converted PyTorch encoder with.
//   npm install --prefix build/tfjs @tensorflow/tfjs@4.22.0
//   NODE_PATH=build/tfjs/node_modules node scripts/pretrained_backbone_reference.js \
//     build/pretrained > test/training/mobilenet_v2_tfjs_reference.json
// (build/pretrained: scripts/pretrained_backbone.py fetch). Per output: its shape (H, W, C), the
// features index of torchvision's mobilenet_v2 that ends there, and 400 values at fixed indices
// of the flattened HWC tensor.
const fs = require('fs');
const path = require('path');
const tf = require('@tensorflow/tfjs');

const dir = process.argv[2];
const model = JSON.parse(fs.readFileSync(path.join(dir, 'model.json')));
const raw = fs.readFileSync(path.join(dir, 'weights.bin'));
const H = 224, W = 224;
// The same integer image as reference_image() in pretrained_backbone.py (RGB).
function image() {
  const v = new Float32Array(H * W * 3);
  for (let y = 0; y < H; ++y)
    for (let x = 0; x < W; ++x) {
      const i = (y * W + x) * 3;
      v[i] = (3 * x + 5 * y + x * y) % 256;
      v[i + 1] = (x * x + 2 * y) % 256;
      v[i + 2] = (7 * x + y * y) % 256;
    }
  return v;
}
const outputs = {Conv1_relu: 0, block_2_add: 3, block_5_add: 6, block_10_project_BN: 11};

(async () => {
  await tf.setBackend('cpu');
  const weightData = raw.buffer.slice(raw.byteOffset, raw.byteOffset + raw.byteLength);
  const net = await tf.loadLayersModel(tf.io.fromMemory({
    modelTopology: model.modelTopology, weightSpecs: model.weightsManifest.flatMap(g => g.weights), weightData}));
  const sub = tf.model({inputs: net.inputs, outputs: Object.keys(outputs).map(n => net.getLayer(n).output)});
  const x = tf.tensor4d(image(), [1, H, W, 3]).div(127.5).sub(1);
  const ys = sub.predict(x);
  const out = {package: 'nsfwjs@4.3.0', tfjs: tf.version.tfjs, height: H, width: W, outputs: {}};
  Object.keys(outputs).forEach((name, k) => {
    const t = ys[k];
    const flat = t.dataSync();
    const shape = t.shape.slice(1);
    let seed = 12345 + k;  // a fixed linear congruential sequence of indices (32-bit)
    const idx = [], values = [];
    for (let j = 0; j < 400; ++j) {
      seed = (Math.imul(seed, 1103515245) + 12345) >>> 0;
      const i = seed % flat.length;
      idx.push(i);
      values.push(Number(flat[i].toPrecision(7)));
    }
    out.outputs[name] = {features_index: outputs[name], shape, indices: idx, values};
  });
  process.stdout.write(JSON.stringify(out) + '\n');
})().catch(e => { console.error('pretrained_backbone_reference: ' + e); process.exit(1); });
