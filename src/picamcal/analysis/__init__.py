"""Analyses of corrected images: finding and comparing the colour wheels of the test target, diagnostics."""
