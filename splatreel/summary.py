"""What a model holds in a few numbers: the summary ``splatreel info`` prints and every checkpoint stores.

`model_summary` is computed from the model (torch) when a checkpoint is written (`splatreel.checkpoint`), and
stored in its metadata under ``"summary"``, so that ``info`` can print it without torch. Its keys: ``kind``,
``count``, ``time_range``, ``bounds_min``/``bounds_max`` (the visible means over 9 times, `model_bounds`),
``sh_degree``, ``sh_degree_t``, ``rotation_convention``, ``motion`` (native 4D models: ``linear``, or ``quadratic``
with accelerations; skinned models: ``nodes``), ``dtype``, ``num_frames`` (keyframed models), ``num_nodes`` and
``num_keys`` (skinned models: control nodes, and their key times),
``std_dev`` and ``opacity`` (median, 99th percentile; max for std-dev) and ``large`` (see `shape_stats`).
"""

from __future__ import annotations

import numpy as np

#: A Gaussian whose largest std-dev exceeds this share of the bounds' diagonal counts as large.
LARGE_SHARE = 0.1


def sizes_and_opacities(model) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(largest std-dev ``[N]``, opacity ``[N]``) as float64 arrays: the opacity at its temporal peak for native 4D
    and skinned models, at the middle time for keyframed ones."""
    import torch

    if not len(model):
        return None, None
    g = model.slice(0.5 * (model.time_range[0] + model.time_range[1]))  # 4D: the covariances do not change with t
    with torch.no_grad():
        if g.scales is not None:  # keyframed: the eigenvalues of R diag(s)^2 Rᵀ are s^2, read them exactly
            std = g.scales.double().max(-1).values.numpy()
        else:
            std = torch.linalg.eigvalsh(g.covariances.double()).clamp_min(0.0)[:, -1].sqrt().numpy()
        native = model.gaussians if model.kind == "skinned" else model  # skinned: the native opacities it carries
        logits = getattr(native, "opacity_logits", None)
        opacity = (torch.sigmoid(logits) if logits is not None else g.opacities).double().numpy()
    return std, opacity


def shape_stats(std, opacity, diagonal: float) -> dict:
    """Sizes and opacities of the Gaussians from each one's largest std-dev `std` and its `opacity` (``[N]``
    float64 arrays, None for no Gaussians): ``std_dev`` (median, 99th percentile, max), ``opacity`` (median, 99th
    percentile) and ``large`` (how many have a std-dev over LARGE_SHARE of the bounds' `diagonal`: the splats
    that fill the screen up close, see view/render --max-screen-radius)."""
    if std is None or not len(std):
        return {"std_dev": None, "opacity": None, "large": 0}

    def rounded(v) -> float:
        return float(f"{float(v):.6g}")

    def quantiles(x, *extra) -> dict:
        out = {"median": rounded(np.median(x)), "p99": rounded(np.quantile(x, 0.99))}
        return {**out, **{name: rounded(f(x)) for name, f in extra}}

    return {"std_dev": quantiles(std, ("max", np.max)), "opacity": quantiles(opacity),
            "large": int((std > LARGE_SHARE * diagonal).sum())}


def model_summary(model) -> dict:
    """The JSON-able summary of `model` (see module doc)."""
    from .model import model_bounds

    lo, hi = (b.double().numpy() for b in model_bounds(model))
    std, opacity = sizes_and_opacities(model)
    out = {"kind": model.kind, "count": len(model), "time_range": [float(t) for t in model.time_range],
           "bounds_min": [round(float(x), 6) for x in lo], "bounds_max": [round(float(x), 6) for x in hi],
           "sh_degree": int(model.sh_degree), "sh_degree_t": int(getattr(model, "sh_degree_t", 0)),
           "rotation_convention": getattr(model, "rotation_convention", None),
           "dtype": str(next(iter(model.tensors().values())).dtype).replace("torch.", "")}
    if model.kind == "keyframed":
        out["num_frames"] = int(model.num_frames)
    if model.kind == "gaussians4d":
        out["motion"] = "linear" if model.accelerations is None else "quadratic"
    if model.kind == "skinned":
        out.update(motion="nodes", num_nodes=int(model.num_nodes), num_keys=int(model.num_keys))
    return {**out, **shape_stats(std, opacity, float(np.linalg.norm(hi - lo)))}
