"""The choices of the SR settings (core/sr/sr_config.SRConfig), apart from the modules that act on them.

Plain tuples, so that the configuration (and every process that reads it, e.g. the map server)
loads without torch; each module that implements a mode re-exports its tuple.
"""
from __future__ import annotations

__all__ = ['ALIGN_MODES', 'CLAMP_MODES', 'FLOW_MODES', 'LAMBDA_MODES', 'ROBUST_NORMS', 'SOLVERS', 'WARP_MODES']

#: Local alignment of each frame to the reference (local_align.py).
ALIGN_MODES = ('off', 'translation', 'affine')
#: Clamping of the estimate to the LR range around each pixel (ringing.py); 'auto': off for a PSF chosen
#: from the frames, 'cell' for one given (ringing.resolve_clamp).
CLAMP_MODES = ('auto', 'cell', 'wide', 'off')
#: 'off' or a DIS preset (speed against accuracy of the coarse search) (dense_flow.py).
FLOW_MODES = ('off', 'ultrafast', 'fast', 'medium')
#: The prior weight lambda: adaptive (5.6), fixed, or the dissertation's rule (solvers.py).
LAMBDA_MODES = ('adaptive', 'fixed', 'paper')
#: Robust norm of the data term's residuals (robust_pixels.py).
ROBUST_NORMS = ('off', 'huber', 'lorentzian')
#: Steepest descent (5.5), conjugate gradient (5.13 to 5.16), Levenberg-Marquardt (5.17 to 5.24).
SOLVERS = ('sd', 'cg', 'lm')
#: interpolation of W_k (grid_sample's modes 0 and 2): bilinear, or bicubic (Keys, a = -0.75), whose
#: response falls less towards the HR grid's Nyquist, so the model blurs less than the warp it describes.
WARP_MODES = ('bilinear', 'bicubic')
