"""Gap diagnosis: where the sim-to-real gap lies, which unmodelled effect causes it, how far it
shrinks once that effect is added; and its validation on data with withheld effects.

Reads paired data only (``paired.DiagnosisPairs``): never a surrogate profile or any parameter
of whatever generated the "real" images.
"""
