"""Sorts `perf script` call stacks of a guided render into the guide's stages (by the guide
method on the stack) and into kernels (by the innermost recognisable frame); prints both as
shares of all samples. Used by scripts/bench/profile-guiding.sh; see docs/results/guiding.md."""

import collections
import re
import sys

# Stage: the first rule whose names occur anywhere on the stack.
STAGES = [
    ("training (Adam steps)",
     ("NisGuide::train", "NisGuide::step", "nis::train::descend", "NisGuide as nis_render::guiding::Guide>::update")),
    ("record handling", ("as nis_render::guiding::Guide>::accumulate", "PassSamples::trim")),
    ("density queries (BSDF-sampled directions)", ("pdf_batch",)),
    ("sample queries", ("sample_batch",)),
    ("selection network", ("selection_probabilities",)),
    ("per-vertex cache (context one-blob, first layers)", (">::prepare", "vertex_context")),
    ("path tracing (BVH, BSDF, lights, the wavefront)", ("Integrator", "render::")),
]

# Kernel: the first of the innermost twelve frames that names one.
KERNELS = [
    ("dense layers (gemm)", ("gemm", "column_sums")),
    ("spline transforms", ("Quadratic", "exp_shifted", "softplus", "knots", "transform::")),
    ("one-blob encoding", ("one_blob",)),
    ("ReLU", ("relu",)),
    ("allocation, zeroing, copies",
     ("memset", "memmove", "memcpy", "malloc", "_int_free", "cfree", "unlink_chunk",
      "from_iter", "realloc", "alloc::", "clear_page", "page_fault")),
    ("input checks", ("check_context", "check_points")),
    ("BVH traversal", ("bvh", "Bvh")),
    ("cylindrical map (atan2, sincos)", ("atan", "sincos", "cylindrical")),
    ("Adam", ("adam",)),
]


def first_match(rules, text, default):
    for name, keys in rules:
        if any(k in text for k in keys):
            return name
    return default


def main(path):
    stages, kernels = collections.Counter(), collections.Counter()
    total = 0
    for block in open(path).read().split("\n\n"):
        lines = [l.strip() for l in block.strip().split("\n") if l.strip()]
        if len(lines) < 2:
            continue
        frames = [re.sub(r"^[0-9a-f]+\s+", "", l) for l in lines[1:]]
        stages[first_match(STAGES, "\n".join(frames), "other (start-up, I/O; allocator frames whose callers perf cannot see)")] += 1
        kernel = "other"
        for f in frames[:12]:
            k = first_match(KERNELS, f, None)
            if k:
                kernel = k
                break
        kernels[kernel] += 1
        total += 1
    print(f"{total} samples")
    for title, counts in (("stage", stages), ("kernel", kernels)):
        print(f"\nby {title}:")
        for name, c in counts.most_common():
            print(f"  {100 * c / total:5.1f}%  {name}")


if __name__ == "__main__":
    main(sys.argv[1])
