// spz-js (pinned in package.json) as a command for test_splat_interop.py:
//   node spzjs.mjs to-ply IN.spz OUT.ply   its SPZ loader, then its PLY writer
//   node spzjs.mjs to-spz IN.ply OUT.spz   its PLY loader, then its SPZ writer (version 2)
// The modules are imported one by one: the package's index also loads its compressed-PLY
// code, which needs the whole PlayCanvas engine.
import { readFileSync, writeFileSync } from 'node:fs';
import { dirname, join } from 'node:path';
import { fileURLToPath } from 'node:url';

const dist = join(dirname(fileURLToPath(import.meta.url)), 'node_modules', 'spz-js', 'dist');
const [command, input, output] = process.argv.slice(2);
if (command === 'to-ply') {
  const { loadSpz } = await import(join(dist, 'spz-loader.js'));
  const { serializePly } = await import(join(dist, 'ply-serializer.js'));
  const cloud = await loadSpz(new Uint8Array(readFileSync(input)));
  writeFileSync(output, new Uint8Array(serializePly(cloud)));
} else if (command === 'to-spz') {
  const { loadPly } = await import(join(dist, 'ply-loader.js'));
  const { serializeSpz } = await import(join(dist, 'spz-serializer.js'));
  const bytes = readFileSync(input);
  const stream = new ReadableStream({
    start(controller) {
      controller.enqueue(new Uint8Array(bytes));
      controller.close();
    },
  });
  writeFileSync(output, await serializeSpz(await loadPly(stream)));
} else {
  console.error('usage: node spzjs.mjs to-ply IN.spz OUT.ply | to-spz IN.ply OUT.spz');
  process.exit(2);
}
