// Print the container fields of KTX2 files as JSON, read with ktx-parse (an independent KTX2
// parser, not the encoder that wrote them). Usage: node tools/inspect_ktx2.mjs FILE.ktx2 ...
import { readFileSync } from "node:fs";
import { read } from "ktx-parse";

const out = process.argv.slice(2).map((file) => {
  const container = read(new Uint8Array(readFileSync(file)));
  const dfd = container.dataFormatDescriptor[0];
  return {
    file,
    vkFormat: container.vkFormat,
    pixelWidth: container.pixelWidth,
    pixelHeight: container.pixelHeight,
    layerCount: container.layerCount,
    faceCount: container.faceCount,
    levelCount: container.levels.length,
    supercompressionScheme: container.supercompressionScheme,
    colorModel: dfd.colorModel,
    transferFunction: dfd.transferFunction,
  };
});
console.log(JSON.stringify(out));
