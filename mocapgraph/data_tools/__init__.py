"""Captures, motion sources, synthetic scenes, detectors, metrics and reports."""
