"""Calibrate a surrogate profile to a user's own sensor from paired (depth, real) frames.

``python -m tactile_bench calibrate PAIRS --out DIR`` splits the pairs into a fit half and a
held-out half, fits on the fit half only what a profile needs (the no-contact field, the
effects the gap diagnosis selects, the optical-response lookup, the camera noise), writes
``DIR/profile.yaml`` and scores it on the held-out half (``calibration.json``,
``calibration.md``). It reads only the user's folder, never a built-in profile.
"""
