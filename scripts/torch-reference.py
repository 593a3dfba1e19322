#!/usr/bin/env python3
"""The scalable PV-RNN in PyTorch: the peer a PyTorch user would write, for timing the wgpu
backend against on the same GPU in the same call (docs/gpu.md), and checked against
`pvrnn free-energy` so that both compute the same model (docs/model.md).

    # a learning iteration at the paper's scale (18 x 300, 32,256 + 28 dims), eager and
    # with the whole iteration captured once in a CUDA graph and replayed:
    python3 scripts/torch-reference.py time --mode eager --device cuda
    python3 scripts/torch-reference.py time --mode graph --device cuda

    # the free energy (eps = 0) and every gradient of a model on its inputs, against
    # `pvrnn free-energy --zero-noise --grads G`:
    python3 scripts/torch-reference.py check --model M.safetensors --inputs X.safetensors \
        --pvrnn target/release/pvrnn

`time` prints one JSON object per line (seconds per iteration, the free energies), as
`pvrnn bench --json` does. One iteration: fresh eps, the forward pass over every step (the
four modules top-down, then both read-outs over all steps at once), the free energy, its
backward pass, and RAdam (torch.optim.RAdam: PyTorch rectifies when rho_t > 5, the project
when rho_t > 4; the arithmetic is the same). Requires torch, numpy and safetensors.
"""

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

# (name, d, z, tau of the first half / second half, parent): docs/model.md.
MODULES = [
    ("executive", 30, 30, (8.0, 16.0), None),
    ("associative", 30, 30, (4.0, 8.0), 0),
    ("exteroceptive", 30, 40, (2.0, 4.0), 1),
    ("proprioceptive", 30, 30, (2.0, 4.0), 1),
]
VISION_DIMS = 32256
PROPRIO_DIMS = 28
KL_WEIGHT = 0.005


def xavier(out_dim, in_dim, gen):
    std = math.sqrt(2.0 / (in_dim + out_dim))
    return torch.randn(out_dim, in_dim, generator=gen) * std


def fresh_params(sequences, steps, seed=0):
    """Xavier-normal weights, N(0, 10) recurrent biases, the paper's taus, zero a's."""
    gen = torch.Generator().manual_seed(seed)
    p = {}
    for name, d, z, (fast, slow), parent in MODULES:
        p[f"{name}.w_dd"] = xavier(d, d, gen)
        p[f"{name}.w_dz"] = xavier(d, z, gen)
        if parent is not None:
            p[f"{name}.w_dh"] = xavier(d, MODULES[parent][1], gen)
        p[f"{name}.bias"] = torch.randn(d, generator=gen) * math.sqrt(10.0)
        p[f"{name}.tau"] = torch.tensor([fast] * (d // 2) + [slow] * (d - d // 2))
        p[f"{name}.w_prior_mu"] = xavier(z, d, gen)
        p[f"{name}.w_prior_sigma"] = xavier(z, d, gen)
        p[f"{name}.a_mu"] = torch.zeros(sequences, steps, z)
        p[f"{name}.a_sigma"] = torch.zeros(sequences, steps, z)
    p["exteroceptive.fnn.0.weight"] = xavier(40, 30, gen)
    p["exteroceptive.fnn.0.bias"] = torch.zeros(40)
    p["exteroceptive.fnn.1.weight"] = xavier(50, 40, gen)
    p["exteroceptive.fnn.1.bias"] = torch.zeros(50)
    p["exteroceptive.out.weight"] = xavier(VISION_DIMS, 50, gen)
    p["proprioceptive.fnn.0.weight"] = xavier(40, 30, gen)
    p["proprioceptive.fnn.0.bias"] = torch.zeros(40)
    p["proprioceptive.out.weight"] = xavier(PROPRIO_DIMS, 40, gen)
    return p


FIXED = ("bias", "tau")


def trainable(params):
    return {k: v for k, v in params.items() if k.rsplit(".", 1)[-1] not in FIXED or ".fnn." in k}


def free_energy(p, x_extero, x_proprio, eps):
    """F summed over every step of every sequence (docs/model.md): accuracy per modality
    divided by its dimensions, plus W times each module's KL divided by its z."""
    sequences, steps, _ = x_extero.shape
    h = [x_extero.new_zeros(sequences, d) for _, d, _, _, _ in MODULES]
    d_prev = [torch.zeros_like(hm) for hm in h]
    kl = x_extero.new_zeros(())
    states = {2: [], 3: []}
    for t in range(steps):
        d_now = [None] * 4
        for m, (name, _, z, _, parent) in enumerate(MODULES):
            mu_p = torch.tanh(d_prev[m] @ p[f"{name}.w_prior_mu"].T)
            log_sigma_p = d_prev[m] @ p[f"{name}.w_prior_sigma"].T
            mu_q = torch.tanh(p[f"{name}.a_mu"][:, t])
            log_sigma_q = p[f"{name}.a_sigma"][:, t]
            sigma_q = torch.exp(log_sigma_q)
            zt = mu_q + sigma_q * eps[m][:, t]
            inv_var_p = torch.exp(-2.0 * log_sigma_p)
            kl_units = (log_sigma_p - log_sigma_q
                        + 0.5 * (sigma_q * sigma_q + (mu_q - mu_p) ** 2) * inv_var_p - 0.5)
            kl = kl + KL_WEIGHT * kl_units.sum() / z
            u = d_prev[m] @ p[f"{name}.w_dd"].T + zt @ p[f"{name}.w_dz"].T + p[f"{name}.bias"]
            if parent is not None:
                u = u + d_now[parent] @ p[f"{name}.w_dh"].T
            inv_tau = 1.0 / p[f"{name}.tau"]
            h[m] = (1.0 - inv_tau) * h[m] + inv_tau * u
            d_now[m] = torch.tanh(h[m])
            if m in states:
                states[m].append(d_now[m])
        d_prev = d_now
    de = torch.stack(states[2], 1)
    dp = torch.stack(states[3], 1)
    e = torch.tanh(de @ p["exteroceptive.fnn.0.weight"].T + p["exteroceptive.fnn.0.bias"])
    e = torch.tanh(e @ p["exteroceptive.fnn.1.weight"].T + p["exteroceptive.fnn.1.bias"])
    x_hat_e = torch.tanh(e @ p["exteroceptive.out.weight"].T)
    q = torch.tanh(dp @ p["proprioceptive.fnn.0.weight"].T + p["proprioceptive.fnn.0.bias"])
    x_hat_p = torch.tanh(q @ p["proprioceptive.out.weight"].T)
    accuracy = (0.5 * ((x_extero - x_hat_e) ** 2).sum() / VISION_DIMS
                + 0.5 * ((x_proprio - x_hat_p) ** 2).sum() / PROPRIO_DIMS)
    return accuracy + kl


def random_data(sequences, steps, device, seed=1):
    gen = torch.Generator().manual_seed(seed)
    x_e = torch.rand(sequences, steps, VISION_DIMS, generator=gen) * 1.8 - 0.9
    x_p = torch.rand(sequences, steps, PROPRIO_DIMS, generator=gen) * 1.8 - 0.9
    return x_e.to(device), x_p.to(device)


def time_iterations(args):
    device = torch.device(args.device)
    torch.manual_seed(0)
    x_e, x_p = random_data(args.sequences, args.steps, device)
    params = {k: v.to(device) for k, v in fresh_params(args.sequences, args.steps).items()}
    learn = trainable(params)
    for v in learn.values():
        v.requires_grad_(True)
    graph = args.mode == "graph"
    opt = torch.optim.RAdam(list(learn.values()), lr=1e-3, betas=(0.9, 0.999),
                            capturable=graph)
    shapes = [(args.sequences, args.steps, z) for _, _, z, _, _ in MODULES]

    def iteration():
        eps = [torch.randn(s, device=device) for s in shapes]
        opt.zero_grad(set_to_none=False)
        f = free_energy(params, x_e, x_p, eps)
        f.backward()
        opt.step()
        return f.detach()

    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    energies, times = [], []
    if graph:
        if device.type != "cuda":
            sys.exit("--mode graph needs --device cuda")
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):
            for _ in range(3):  # warm-up on a side stream, as CUDA graph capture requires
                energies.append(float(iteration()))
        torch.cuda.current_stream().wait_stream(side)
        g = torch.cuda.CUDAGraph()
        with torch.cuda.graph(g):
            static_f = iteration()
        for _ in range(args.iterations):
            sync()
            start = time.perf_counter()
            g.replay()
            sync()
            times.append(time.perf_counter() - start)
            energies.append(float(static_f))
    else:
        energies.append(float(iteration()))  # warm-up
        for _ in range(args.iterations):
            sync()
            start = time.perf_counter()
            f = iteration()
            sync()
            times.append(time.perf_counter() - start)
            energies.append(float(f))
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"
    print(json.dumps({
        "backend": f"pytorch {torch.__version__} {args.mode} on {name}",
        "sequences": args.sequences,
        "steps": args.steps,
        "train_iter_s": sum(times) / len(times),
        "train_iter_min_s": min(times),
        "train_free_energy": energies,
        "peak_gpu_mb": (torch.cuda.max_memory_allocated(device) / 1e6
                        if device.type == "cuda" else None),
    }))


def check(args):
    """F (eps = 0) and every gradient against the project's CPU backend."""
    from safetensors.numpy import load_file
    model = load_file(args.model)
    inputs = load_file(args.inputs)
    params = {k: torch.from_numpy(v.astype(np.float64)) for k, v in model.items()
              if k in fresh_params(1, 1)}
    learn = trainable(params)
    for v in learn.values():
        v.requires_grad_(True)
    x_e = torch.from_numpy(inputs["x_extero"].astype(np.float64))
    x_p = torch.from_numpy(inputs["x_proprio"].astype(np.float64))
    eps = [torch.zeros(x_e.shape[0], x_e.shape[1], z, dtype=torch.float64)
           for _, _, z, _, _ in MODULES]
    f = free_energy(params, x_e, x_p, eps)
    f.backward()
    with tempfile.TemporaryDirectory() as tmp:
        grads_path = Path(tmp) / "grads.safetensors"
        out = subprocess.run(
            [args.pvrnn, "free-energy", "--model", args.model, "--inputs", args.inputs,
             "--zero-noise", "--grads", str(grads_path)],
            check=True, capture_output=True, text=True).stdout
        theirs = json.loads(out)
        their_grads = load_file(str(grads_path))
    total = theirs["total"] if "total" in theirs else theirs["free_energy"]["total"]
    f = float(f.detach())
    rel = abs(f - total) / abs(total)
    # Each gradient against its tensor's largest value; a gradient that is zero up to
    # rounding (the KL's at a posterior equal to its prior) against 1e-4 of the
    # largest of all.
    theirs_g = {name: their_grads[f"grad.{name}"].astype(np.float64) for name in learn}
    floor = 1e-4 * max(np.abs(g).max() for g in theirs_g.values())
    worst, worst_name = 0.0, None
    for name, v in learn.items():
        g = theirs_g[name]
        scale = max(np.abs(g).max(), floor)
        diff = float(np.abs(v.grad.numpy() - g).max() / scale)
        if diff > worst:
            worst, worst_name = diff, name
    print(json.dumps({"torch_free_energy": f, "pvrnn_free_energy": total,
                      "relative_difference": rel, "worst_gradient_difference": worst,
                      "worst_gradient": worst_name}))
    if rel > 1e-5 or worst > 1e-3:
        sys.exit(f"the PyTorch reference disagrees with pvrnn: F {rel:.2e} relative, "
                 f"gradients {worst:.2e} of their largest value")


def main():
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    t = sub.add_parser("time", help="seconds per learning iteration")
    t.add_argument("--mode", choices=["eager", "graph"], default="eager")
    t.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    t.add_argument("--sequences", type=int, default=18)
    t.add_argument("--steps", type=int, default=300)
    t.add_argument("--iterations", type=int, default=10)
    c = sub.add_parser("check", help="F and gradients against pvrnn free-energy")
    c.add_argument("--model", required=True)
    c.add_argument("--inputs", required=True)
    c.add_argument("--pvrnn", default="target/release/pvrnn")
    args = parser.parse_args()
    time_iterations(args) if args.command == "time" else check(args)


if __name__ == "__main__":
    main()
