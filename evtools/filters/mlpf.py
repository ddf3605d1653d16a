"""MLPF, the learned filter (Guo & Delbruck 2022): a small perceptron on time-surface patches
(:mod:`evtools.mlpf`)."""

from __future__ import annotations

import math

import numpy as np

from evtools._kernels import mlpf as mlpf_kernels
from evtools.filters.spec import BAFilterError, Filter, Param


class Mlpf(Filter):
    name = "mlpf"
    reference = "Guo & Delbruck 2022"
    keeps = ("a small perceptron says it is signal with probability above `--threshold` (Guo & Delbruck 2022's "
             "MLPF; see below)")
    params = (
        Param("threshold", "probability", "keep an event when its probability of being signal is above this"),
        Param("weights", "weights", "weights from `evtools metrics train-denoiser` (an .npz path)", sweepable=False),
    )
    defaults = {"evtools": {"threshold": 0.5, "weights": None}}
    default_notes = {"weights": "the shipped ones"}

    @classmethod
    def prepare(cls, q, width, height):
        from evtools.mlpf import MlpfError, Weights, load_weights  # (the model's module only where it is used)

        try:
            q["weights"] = (q["weights"].check("weights") if isinstance(q["weights"], Weights)
                            else load_weights(q["weights"]))
        except MlpfError as error:
            raise BAFilterError(str(error)) from None
        return q

    def __init__(self, width, height, preset, q) -> None:
        super().__init__(width, height, preset, q)
        weights = self.weights = q["weights"]
        self.time_map = mlpf_kernels.padded_maps(width, height, weights.radius)
        self.logit = math.log(q["threshold"] / (1.0 - q["threshold"]))
        self.clock, self.scale = mlpf_kernels.new_clock(width * height), weights.tau_scale * (width * height)
        self.w1 = mlpf_kernels.with_zero_row(weights.w1)
        self.cells, self.ages = mlpf_kernels.scratch(weights.patch)
        self.hidden = np.empty(len(weights.b1))

    def record(self):
        return {**super().record(), "weights": self.weights.info.get("file", "given")}

    def run(self, words, out) -> int:
        w = self.weights
        return mlpf_kernels.mlpf(words, self.time_map, w.radius, self.clock, self.scale, w.tau_us, self.w1, w.b1,
                                 w.w2, w.b2, self.logit, self.cells, self.ages, self.hidden, out)
