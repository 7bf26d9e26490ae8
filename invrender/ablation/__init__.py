"""Ablation of sampling strategies (``invrender ablation``): each choice of the path tracer's
sampling changed alone, its RMSE against a high-spp reference at equal samples and at equal time
(docs/sampling.md#ablation)."""

from invrender.ablation.measure import AblationResult, Measurement, ablation
from invrender.ablation.report import format_table, plot, write_ablation, write_csv
from invrender.ablation.variants import VARIANTS, Variant, select_variants

__all__ = ["VARIANTS", "AblationResult", "Measurement", "Variant", "ablation", "format_table", "plot", "select_variants", "write_ablation", "write_csv"]
