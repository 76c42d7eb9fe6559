"""Recordings of comparisons (``bananagrid compare``) and of the Figure 7 sweep
(``bananagrid sweep``).

A comparison recording holds both layers as usual (``layers/REFERENCE``, ``layers/MODEL``,
see :func:`record.log_raster`; their maps in one colour range, with a shared colour bar), the model's relative error q / p - 1 as an image in world
metres (``compare/relative_error``: diverging colormap, symmetric range; 0 where the reference
is below the lowest contour level, where the table does not look), the table as a text
document (``compare/table``) and its numbers as ``AnyValues`` (``compare/summary``).

A sweep recording holds the goodness map (``sweep/goodness`` as an image over sigma_a t / v0
(x, 0 to 0.2) and sigma_omega t (y, 0 to 75 deg, up), one pixel per setting), the contour lines
of Figure 7's levels (``sweep/contours``, in the same pixel coordinates), and the claim check
(``sweep/claim``, text).
"""

from __future__ import annotations

import math
from pathlib import Path

import contourpy
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ..analysis.compare import Comparison
from ..results import Raster
from .core import default_blueprint, log_scene_text, log_signed_image, send_blueprint, strict, write_recording
from .layers import log_shared_colours
from .raster import log_raster_layer

__all__ = ["write_compare_recording", "write_sweep_recording"]


def log_relative_error(rec: rr.RecordingStream, path: str, reference: Raster, comparison: Comparison, floor: float) -> None:
    """q / p - 1 where p >= ``floor`` (else 0), as an image placed like the layers' densities."""
    error = np.where(reference.values >= floor, np.nan_to_num(comparison.relative_error, nan=0.0), 0.0)
    log_signed_image(rec, path, error, reference)


def write_compare_recording(
    path: Path, *, recording_id: str, scene_text: str, names: tuple[str, str], rasters: tuple[Raster, Raster],
    comparison: Comparison, levels, colormap: str = "viridis",
) -> None:
    """Write the comparison of ``rasters`` = (reference, model) named ``names`` to ``path``."""
    reference, model = rasters

    def build(rec):
        log_scene_text(rec, scene_text)
        logged = {f"layers/{name}": [log_raster_layer(rec, f"layers/{name}", raster, levels=levels, colormap=colormap)]
                  for name, raster in zip(names, rasters)}
        colours = log_shared_colours(rec, logged)  # side by side: one colour range
        north_up = "compare"
        rec.log(north_up, rr.Transform3D(scale=(1.0, -1.0, 1.0)), static=True)
        log_relative_error(rec, "compare/relative_error", reference, comparison, min(levels))
        with strict():
            rec.log("compare/table", rr.TextDocument(f"```\n{comparison.table()}\n```", media_type=rr.MediaType.MARKDOWN))
            rec.log("compare/summary", rr.AnyValues(**comparison.summary()))
        # sent last, as a scene run's: the maps' colour range is known once both are logged
        send_blueprint(rec, default_blueprint(
            [f"layers/{n}" for n in names], text_entities=["compare/table"],
            extra_views=[rrb.Spatial2DView(origin="/", contents=["/compare/relative_error"], name="relative error")],
            colours=colours, frames={entity: maps[0].frame for entity, maps in logged.items()},
        ))

    write_recording(path, build, recording_id=recording_id)


def write_sweep_recording(path: Path, result, *, recording_id: str, levels, stage=None) -> None:
    """Write a :class:`sweep.SweepResult` as the Figure 7 map with its contours (``stage``: as
    for :func:`~bananagrid.recording.core.write_recording`)."""
    n_beta, n_alpha = result.goodness.shape
    claim = result.claim()

    def build(rec):
        with strict():
            rec.log(
                "sweep/goodness",
                rr.DepthImage(np.ascontiguousarray(np.flipud(result.goodness), dtype=np.float32), meter=1.0,
                              colormap="viridis", depth_range=(float(result.goodness.min()), 1.0)),
            )
            # pixel coordinates: column j + 1/2, row k + 1/2 from the top (largest beta)
            generator = contourpy.contour_generator(
                np.arange(n_alpha) + 0.5, np.arange(n_beta) + 0.5, np.flipud(result.goodness)
            )
            strips = [line for level in levels for line in generator.lines(level) if len(line) > 1]
            if strips:
                rec.log("sweep/contours", rr.LineStrips2D(strips, colors=[(255, 255, 255)]))
            rec.log("sweep/claim", rr.TextDocument(_claim_text(result, claim), media_type=rr.MediaType.MARKDOWN))
            rec.log("sweep/summary", rr.AnyValues(
                least_goodness_in_claim_region=claim["least_goodness_in_claim_region"],
                n=float(n_alpha), threshold=result.threshold, seconds=result.seconds,
            ))

    blueprint = rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(origin="/sweep", contents=["/sweep/goodness", "/sweep/contours"], name="goodness (Figure 7)"),
            rrb.TextDocumentView(origin="/sweep/claim", name="claim"),
            column_shares=[3, 1],
        ),
        collapse_panels=False,
    )
    write_recording(path, build, recording_id=recording_id, blueprint=blueprint, stage=stage)


def _claim_text(result, claim) -> str:
    rows = "\n".join(
        f"| {a:.4f} | {b:.1f} |" for a, b in zip(result.alpha, claim["contour_999_beta_deg"]) if not math.isnan(b)
    )
    verdict = "holds" if claim["claim_holds_on_grid"] else "does not hold"
    return (
        f"Goodness of the improved approximation, {len(result.alpha)} x {len(result.beta)} settings, "
        f"threshold {100 * result.threshold:g}%.\n\n"
        "Paper (Section 6.3): sigma_a t / v0 < 0.1 and sigma_omega t < 42 deg => goodness >= 99.9%.\n"
        f"Least goodness over the grid's settings in that region: {claim['least_goodness_in_claim_region']:.6f}: "
        f"the claim {verdict} on this grid.\n\n"
        "Where the 99.9% contour lies (largest sigma_omega t, from 0 up, with goodness >= 0.999):\n\n"
        "| sigma_a t / v0 | sigma_omega t [deg] |\n|---|---|\n" + rows + "\n\n"
        "Image: x = sigma_a t / v0 from 0 (left) to 0.2, y = sigma_omega t from 0 (bottom) to 75 deg; "
        "one pixel per setting."
    )
