"""``evtools metrics``: the group of measurements; each subcommand lives in its own ``cli/metrics_*.py`` module."""

from __future__ import annotations

import click

from evtools.cli.main import LazyGroup


@click.group(cls=LazyGroup, lazy_commands={
    "denoise": ("evtools.cli.metrics_denoise:denoise",
                "TPR (signal kept), FPR (noise kept), precision, F1 and per-label counts of FILTERED against NOISY."),
    "roc": ("evtools.cli.metrics_denoise:roc",
            "DND21 ROC of each --method over --sweep on NOISY: (FPR, TPR) per value, (0,0) and (1,1), trapezoid "
            "AUC."),
    "esr": ("evtools.cli.metrics_denoise:esr",
            "E-MLB's event structural ratio per slice of IN and its mean, MESR (higher is better; no labels "
            "needed)."),
    "thresholds": ("evtools.cli.metrics_thresholds:thresholds",
                   "Relative RMSE, bias and correlation of ON and OFF thresholds over valid pixels, the invalid "
                   "fraction, the valid pixels more than 10 % off, and how well the fit map predicts the error "
                   "(natural, offe, frames)."),
    "reconstruction": ("evtools.cli.metrics_reconstruction:reconstruction",
                       "RMSE and SSIM of the log intensity reconstructed from EVENTS against the true frames of "
                       "TRUTH.h5; without --truth, how well EVENTS predict their own APS frames (a DAVIS "
                       "recording)."),
    "train-denoiser": ("evtools.cli.metrics_train:train_denoiser",
                       "Train the MLPF filter (`bafilter --method mlpf --weights FILE`) on RECORDINGS."),
    "uniformity": ("evtools.cli.metrics_uniformity:uniformity",
                   "Per stimulus edge of IN: std across pixels of the first and last event times, count CV, errors "
                   "vs IDEAL."),
})
def metrics() -> None:
    """Measure denoising (denoise, roc, esr), threshold estimation (thresholds), uniformity (uniformity) and
    reconstruction (reconstruction).

    Each prints a table on a terminal and JSON when stdout is not a terminal or with --json.
    """
