// The inference worker: the explorer's own wasm module, run without a page. It computes
// live runs beside the page's thread (crates/pvrnn-explorer/src/worker.rs).
import init, { run_worker } from "./pvrnn-explorer.js";

await init();
run_worker();
