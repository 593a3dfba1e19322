// The inference worker: the explorer's own wasm module, run without a page. It computes
// live runs beside the page's thread (crates/pvrnn-explorer/src/worker.rs).
import init, { run_worker } from "./pvrnn-explorer.js";

await init();
// Where runs compute (auto, cpu or webgpu): the page passes its own `?compute=`.
const page = new URLSearchParams(self.location.search);
run_worker(page.get("compute") ?? "auto");
