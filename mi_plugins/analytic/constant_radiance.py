"""Constant-radiance cases (paper section 2): filled in by issue 3."""

#: name -> factory(resolution=...) of this module's cases in the verification matrix
MATRIX_CASES = {}
QUICK_CASES = ()
