// Builds the console's front end into dist/: one bundled, minified script (three.js and
// urdf-loader included: nothing is loaded from elsewhere at run time), the AudioWorklet
// processor, the WebSocket's worker, the page and its style. Run by `npm run build` (make setup).
import { build } from 'esbuild';
import { copyFileSync, mkdirSync, rmSync } from 'node:fs';

const out = new URL('./dist/', import.meta.url).pathname;
rmSync(out, { recursive: true, force: true });
mkdirSync(out, { recursive: true });
const common = { bundle: true, minify: true, target: 'es2020', legalComments: 'eof', logLevel: 'warning' };
await build({ ...common, entryPoints: ['src/main.js'], outfile: `${out}console.js`, format: 'iife' });
await build({ ...common, entryPoints: ['src/worklet.js'], outfile: `${out}worklet.js`, format: 'esm' });
await build({ ...common, entryPoints: ['src/link.js'], outfile: `${out}link.js`, format: 'iife' });
for (const file of ['index.html', 'console.css']) {
  copyFileSync(new URL(`./src/${file}`, import.meta.url), `${out}${file}`);
}
console.log(`built ${out}`);
