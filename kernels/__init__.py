"""Warp device code for bananagrid, installed as ``bananagrid.kernels``.

Only Warp device code lives here; nothing imports from ``bananagrid``. One module per model
family, so each compiles as one unit. A family module holds maths: a ``@wp.func`` density over a
typed parameter struct (:class:`generate.Params`), from which :func:`generate.density_kernels`
writes the grid, points and batch kernels (scalar, and in CPU lanes where the family writes a
lane density) into the family's own module; only kernels of another shape (Butterly's tiles,
the CAT's scan table, cell rules) are written by hand.

Overloads are registered on first use, so that a run builds the kernels it launches and no
others, one module per family still (``generate.overload_on_use``; the module docstring of
``kernels/generate.py`` says why).

Module options, and why. Every module sets ``enable_backward = False``: nothing differentiates
these kernels, and Warp otherwise generates an adjoint kernel beside every launch kernel, most
of a module's code. The CAT, CAT-lane and presence modules also cap ``max_unroll`` below the
trip count of their heaviest constant loops (the CAT scan's two levels of SPLIT parts, the
presence rules' GK_NODES nodes): Warp unrolls constant loops of up to 16 trips, and each
unrolled trip inlined a whole root search or ray integral. A GPU build compiles each module once
per machine (NVRTC, one core, then Warp's kernel cache), and the CAT module's build was what
kept the CAT from giving any result on a GPU (and the Butterly cases, run after it in the same
test process: Butterly's own module as it was builds in 22 s by NVRTC here, 12 s now). Measured
on the H100 machine, each module's CUDA build alone from an empty cache: the CAT module as it
was gave no result within 330 s; with the options CAT 34 s, Butterly 12.5 s, presence 23 s
(153 s with adjoints dropped but its node loops unrolled). NVRTC on a CPU-only machine shows the same (``warp.compile_aot_module`` for
sm_90, a loaded 2-core machine): CAT 123 s with adjoints dropped but its loops unrolled, 52 s
with both options; presence 777 s unrolled, 53 s capped. The CPU builds shrink too (presence
19 s -> 7 s).
"""
