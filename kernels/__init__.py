"""Warp device code for bananagrid, installed as ``bananagrid.kernels``.

Only ``@wp.func`` math and ``@wp.kernel`` rasterisers live here; nothing imports from
``bananagrid``. One module per model family, so each compiles as one unit.

Module options, and why. Every module sets ``enable_backward = False``: nothing differentiates
these kernels, and Warp otherwise generates an adjoint kernel beside every launch kernel, most
of a module's code. The CAT, CAT-lane and presence modules also cap ``max_unroll`` below the
trip count of their heaviest constant loops (the CAT scan's two levels of SPLIT parts, the
presence rules' GK_NODES nodes): Warp unrolls constant loops of up to 16 trips, and each
unrolled trip inlined a whole root search or ray integral. A GPU build compiles each module once
per machine (NVRTC, one core, then Warp's kernel cache), and these were what kept the CAT and
Butterly from giving any result on a GPU: on the H100 machine, the CAT module as it was did not
finish its CUDA build within 200 s; with the options it builds in 40 s (Butterly 17 s, presence
153 s before its cap). NVRTC on a CPU-only machine shows the same (``warp.compile_aot_module``
for sm_90): CAT 123 s with adjoints dropped but the loops unrolled, 52 s with both.
"""
