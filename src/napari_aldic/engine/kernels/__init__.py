"""Every Numba kernel of the engine (numpy/numba only).

Each module groups the kernels of one role; the Python wrappers that
validate inputs, allocate outputs and call them live in ``dic/`` (and
``synthetic/``):

* ``flags``    the compilation options, defined once (fast-math set, cache, ...);
* ``bspline``  B-spline weights and samplers (float64 points, float32 IC-GN taps),
  spline gradients at the pixel centres;
* ``prefilter`` B-spline prefilters (recursive line filters; 2-D here, 3-D in
  ``prefilter3d``);
* ``subset``   a node's subset: work buffers, gathering its pixels, noise model;
* ``gauss_newton`` the Gauss-Newton step the IC-GN solvers share (chunks, one
  iteration's sums, storing a node's outcome);
* ``icgn_node`` the per-node pieces every IC-GN driver shares (Cholesky solve,
  work buffers, starting a node, the step verdict);
* ``icgn``     the affine and the penalised-translation IC-GN solvers;
* ``translation`` the per-node pieces of the penalised-translation solver (AL-DIC's
  local step: reference sums, penalised system, predicted start, one step);
* ``icgn_quadratic`` the 12-parameter (second-order) IC-GN solver;
* ``moments``  streaming window moments of the speckle-quality maps (the per-node
  uncertainty from them is batched NumPy, ``dic/covariance``);
* ``noise_sums`` window sums of many noise probes at once (AL-DIC's ``u_std``);
* ``sums``     integral images and window sums;
* ``lattice``  per-node statistics over lattice neighbours (median test, plane fit);
* ``cg``       Jacobi-preconditioned conjugate gradients (the curvature smoother);
* ``speckle``  the analytic speckle intensity of the synthetic images.
"""
