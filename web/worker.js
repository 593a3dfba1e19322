// The inference worker: the explorer's own wasm module, run without a page. It computes
// live runs beside the page's thread (crates/pvrnn-explorer/src/worker.rs).
import init, { run_worker } from "./pvrnn-explorer.js";

await init();
// Where runs compute (auto, cpu or webgpu): the page passes its own `?compute=`.
run_worker(new URLSearchParams(self.location.search).get("compute") ?? "auto");
