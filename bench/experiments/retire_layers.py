"""Experiment (issue 18, docs/LOG.md 15.7): nested layers where part of layers 1..M *retire*
once layer M+1 arrives. It patches encoder internals (private names), so it may stop working when
they change; it is kept to make 15.7 reproducible, not as a feature.

    RETIRE_JSON=map.json python bench/experiments/retire_layers.py encode IN.ply -o F.spc --nested \
        --target-size N --threads 1
    python bench/experiments/judge_retired.py rows.json LABEL F.spc map.json

Runs `spcodec encode` with these changes:
* retraining: every Gaussian of layers 1..M gets a gate (sigmoid, starts at 0.95) that scales its
  opacity in the prefixes that reach past layer M (the whole file included); at HARDEN of the steps
  the gates become hard: gate < 0.5 -> retired (invisible past layer M), else kept as is;
* the finish hides the retired Gaussians in those prefixes;
* the file stores layers 1..M each as two layers, kept then retired (so the retired ones can be
  found after decoding): file layers 0 sketch, 1 A1, 2 R1, ..., 2M-1 AM, 2M RM, then the rest.
The written file is an ordinary spcodec file; retirement is applied by judge_retired.py.
Env: RETIRE_AFTER (M, default 3), HARDEN (0.5), RETIRE_JSON (where the layer map goes).
"""
import json
import os
import sys

import numpy as np
import torch

from spcodec.encoder.retraining import nested as NE
from spcodec.encoder.retraining import quantaware as QA
from spcodec.encoder.retraining import run as PR
from spcodec.encoder.retraining import stage as RT
from spcodec.imaging.render import GaussianParams
from spcodec.imaging.training import optim as OP

M = int(os.environ.get("RETIRE_AFTER", 3))
HARDEN = float(os.environ.get("HARDEN", 0.5))
OUT = os.environ["RETIRE_JSON"]
GATE_INIT = float(os.environ.get("GATE_INIT", 3.0))
GATE_RATE, HIDDEN = 0.05, -40.0
state: dict = {"ends": None, "schedule": None, "retired": None, "log": {}}

_schedule = PR.prefix_schedule


def schedule(ends, seed, share):
    fn = _schedule(ends, seed, share)
    state["ends"], state["schedule"] = list(ends), fn
    return fn


PR.prefix_schedule = schedule


def late(step: int) -> bool:
    count = state["schedule"](step)
    return count is None or count > state["ends"][M - 1]


class GatedGaussians(OP.FreeGaussians):
    def __init__(self, cloud, device, rates, extent):
        super().__init__(cloud, device, rates, extent)
        self.n = state["ends"][M - 1]
        self.gate = torch.full((self.n,), GATE_INIT, device=device, requires_grad=True)
        self.optimizer.add_param_group({"params": [self.gate], "lr": GATE_RATE, "name": "gate"})
        self.late, self.hard = False, None

    def before_step(self, step, total):
        super().before_step(step, total)
        if self.hard is None and step >= int(HARDEN * total):
            with torch.no_grad():
                g = torch.sigmoid(self.gate)
                self.hard = g < 0.5
            for group in self.optimizer.param_groups:
                if group.get("name") == "gate":
                    group["lr"] = 0.0
            state["log"]["gates_at_harden"] = np.percentile(
                g.cpu().numpy(), [5, 25, 50, 75, 95]).round(3).tolist()
            state["log"]["retired_at_harden"] = int(self.hard.sum())
            print(f"[retire] hardened at step {step}: {int(self.hard.sum())} of {self.n} retired",
                  flush=True)
        self.late = late(step)

    def params(self):
        p = super().params()
        if not self.late:
            return p
        o = p.opacities
        if self.hard is not None:
            early = torch.where(self.hard, torch.full_like(o[:self.n], HIDDEN), o[:self.n])
        else:
            a = (torch.sigmoid(o[:self.n]) * torch.sigmoid(self.gate)).clamp(1e-6, 1 - 1e-6)
            early = torch.log(a) - torch.log1p(-a)
        return GaussianParams(p.means, p.scales, p.quats, torch.cat([early, o[self.n:]]), p.sh)

    def to_cloud(self):
        cloud = super().to_cloud()
        retired = np.zeros(len(cloud), bool)
        if self.hard is not None:
            retired[:self.n] = self.hard.cpu().numpy()
        state["retired"] = retired
        return cloud


_model = RT.RetrainStage._model


def model(self, survivors):
    if state["ends"] is None:
        return _model(self, survivors)
    return GatedGaussians(survivors, self.device, self.config.rates, self.targets.extent)


RT.RetrainStage._model = model


class GatedCodebook(QA.CodebookGaussians):
    def before_step(self, step, total):
        super().before_step(step, total)
        self.late = late(step)

    def params(self):
        p = super().params()
        if not getattr(self, "late", False) or state["retired"] is None:
            return p
        r = torch.as_tensor(state["retired"], device=p.opacities.device)
        o = torch.where(r, torch.full_like(p.opacities, HIDDEN), p.opacities)
        return GaussianParams(p.means, p.scales, p.quats, o, p.sh)


RT.CodebookGaussians = GatedCodebook

_fit = PR._rows_that_fit


def rows_that_fit(*args, **kwargs):
    top = _fit(*args, **kwargs)
    if state["retired"] is not None:
        state["retired"] = state["retired"][top]
    return top


PR._rows_that_fit = rows_that_fit

_layer = NE.NestedEncoder.layer


def layer(self, cloud, quantized, importance):
    retired = state["retired"]
    if retired is None or len(retired) != len(cloud):
        return _layer(self, cloud, quantized, importance)
    layer_of = NE.layers_of(importance, self.config.layers)
    groups, kinds = [], []
    for k in range(self.config.layers):
        members = np.flatnonzero(layer_of == k)
        members = members[np.argsort(-importance[members], kind="stable")]
        if k < M:
            groups += [members[~retired[members]], members[retired[members]]]
            kinds += [f"A{k + 1}", f"R{k + 1}"]
        else:
            groups.append(members)
            kinds.append(f"L{k + 1}")
    state["log"]["file_layers"] = {kind: int(len(g)) for kind, g in zip(kinds, groups)}
    state["log"]["kinds"] = kinds
    return self.layer_groups(cloud, quantized, groups)


NE.NestedEncoder.layer = layer

from spcodec.cli import main  # noqa: E402

try:
    rc = main(sys.argv[1:])
finally:
    state["log"]["M"], state["log"]["harden"] = M, HARDEN
    with open(OUT, "w") as f:
        json.dump(state["log"], f, indent=1)
sys.exit(rc)
