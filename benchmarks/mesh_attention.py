"""Cost of EmoFace's spirals, SpiralConv3D and Mesh Attention on the template head (V = 1558), one thread.

    .venv/bin/python benchmarks/mesh_attention.py [--batch-size 8] [--frames 90] [--channels 64 128]
        [--length 18] [--dilation 2] [--delta 3] [--layers 2] [--reps 3]

Prints, in process CPU time (``time.process_time``, one torch thread; less sensitive to other jobs than wall time):
1. building the spirals of every vertex (``spiral_indices``);
2. Mesh Attention forward and backward per training batch (B x T frames), for each channel width C, and its
   first layer split (``MeshAttention.first_layer``) against the plain first layer;
3. autoregressive use: the map of the newest frame from the last ``receptive_field`` frames, per frame, and the
   real-time factor at 30 fps;
4. one SpiralConv3D layer, forward + backward: the package (blocked gather + matmul, ``SpiralLinear``) against the
   plain formulation (one big gather, one matmul: what eq. 3 reads like), with the size of the gathered tensor;
5. the process's peak resident memory (ru_maxrss) before and after the plain formulation.
"""
import argparse
import resource
import statistics
import time

import torch

from dualtalker_lite.blocks import MeshAttention, SpiralConv3D, spiral_indices
from dualtalker_lite.face.mesh import build_template


def cpu_ms(fn, reps: int) -> float:
    """Median process CPU milliseconds of ``fn()`` over ``reps`` runs, after one warm-up run."""
    fn()
    times = []
    for _ in range(reps):
        t0 = time.process_time()
        fn()
        times.append(1e3 * (time.process_time() - t0))
    return statistics.median(times)


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def plain_layer(conv: SpiralConv3D, x: torch.Tensor) -> torch.Tensor:
    """Eq. 3 the direct way: gather (B, T, V, L, C), stack delta frames, flatten, one matmul."""
    g = conv.gather(x)  # (B, T, V, L, C)
    pad = torch.zeros_like(g[:, :1]).expand(-1, conv.delta - 1, -1, -1, -1)
    gp = torch.cat([pad, g], dim=1)
    T = x.shape[1]
    stacked = torch.stack([gp[:, j:j + T] for j in range(conv.delta)], dim=3)  # (B, T, V, delta, L, C)
    return stacked.flatten(3) @ conv.weight.reshape(conv.out_channels, -1).t() + conv.bias


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--batch-size", type=int, default=8)
    p.add_argument("--frames", type=int, default=90)
    p.add_argument("--channels", type=int, nargs="+", default=[64, 128])
    p.add_argument("--length", type=int, default=18)
    p.add_argument("--dilation", type=int, default=2)
    p.add_argument("--delta", type=int, default=3)
    p.add_argument("--layers", type=int, default=2)
    p.add_argument("--reps", type=int, default=3)
    args = p.parse_args()
    torch.set_num_threads(1)
    mesh = build_template()
    V, B, T = mesh.n_vertices, args.batch_size, args.frames

    t0 = time.process_time()
    spirals = spiral_indices(mesh.faces, V, length=args.length, dilation=args.dilation, vertices=mesh.vertices)
    print(f"spiral_indices: V = {V}, L = {args.length}, dilation {args.dilation}: "
          f"{time.process_time() - t0:.3f} CPU s")

    print(f"\nMesh Attention, {args.layers} layers, delta {args.delta}, B x T = {B} x {T} (CPU ms):")
    print(f"{'C':>5} {'params':>7} {'forward':>8} {'backward':>9} {'first layer split':>18} {'plain first':>12}")
    for C in args.channels:
        torch.manual_seed(0)
        att = MeshAttention(V, C, spirals, delta=args.delta, n_layers=args.layers)
        fe, fc = torch.randn(B, T, C), torch.randn(B, T, C)
        me, mc = torch.randn(B, T, 3 * V), torch.randn(B, T, 3 * V)
        state = {}

        def forward():
            state["out"] = att(fe, fc, me, mc)[0]

        def backward():
            att.zero_grad()
            att(fe, fc, me, mc)[0].pow(2).mean().backward()

        fwd = cpu_ms(forward, args.reps)
        both = cpu_ms(backward, args.reps)
        audio = att.audio_feature(fe, fc).detach()
        with torch.no_grad():
            split = cpu_ms(lambda: att.first_layer(audio), args.reps)
            plain = cpu_ms(lambda: att.convs[0](audio[:, :, None] + att.vertex_embedding), args.reps)
        n_params = sum(q.numel() for q in att.parameters())
        print(f"{C:>5} {n_params:>7} {fwd:>8.0f} {both - fwd:>9.0f} {split:>18.1f} {plain:>12.1f}")

    C = args.channels[0]
    torch.manual_seed(0)
    att = MeshAttention(V, C, spirals, delta=args.delta, n_layers=args.layers)
    r = att.receptive_field
    fe, fc = torch.randn(1, r, C), torch.randn(1, r, C)
    with torch.no_grad():
        per_frame = cpu_ms(lambda: att.attention(fe, fc), max(args.reps, 10))
    print(f"\nautoregressive: newest frame's map from the last {r} frames, C = {C}: {per_frame:.1f} CPU ms a frame "
          f"({1000 / 30 / per_frame:.1f}x real time at 30 fps, Mesh Attention alone)")
    print(f"peak resident memory so far (imports, spirals, Mesh Attention): {peak_mb():.0f} MB")

    c16 = max(1, min(args.channels) // 16)
    torch.manual_seed(0)
    conv = SpiralConv3D(c16, c16, spirals, args.delta)
    x = torch.randn(B, T, V, c16, requires_grad=True)
    torch.testing.assert_close(conv(x), plain_layer(conv, x), rtol=1e-4, atol=1e-5)
    gathered_mb = B * T * V * args.length * c16 * 4 / 2**20
    print(f"\none SpiralConv3D layer {c16} -> {c16} channels, B x T = {B} x {T}, forward + backward (CPU ms):")
    print(f"  package (blocked, SpiralLinear): {cpu_ms(lambda: conv(x).sum().backward(), args.reps):7.0f}")
    print(f"  plain gather + one matmul:       {cpu_ms(lambda: plain_layer(conv, x).sum().backward(), args.reps):7.0f}"
          f"   (gathered tensor {gathered_mb:.0f} MB, x{args.delta} once stacked)")

    print(f"peak resident memory after the plain layer: {peak_mb():.0f} MB")


if __name__ == "__main__":
    main()
