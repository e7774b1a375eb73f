"""The DIC algorithm, one module per step of Algorithm 1 (see docs/method.md).

mesh -> subsets -> interpolation -> init_guess -> icgn -> local (Local DIC) ->
outliers -> quadtree -> global_solve -> regularise -> admm -> aldic (AL-DIC) -> correlate;
strain differentiates a result. Public entry points are re-exported by
:mod:`napari_aldic.engine`.
"""
