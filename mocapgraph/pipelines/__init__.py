"""Pipelines (aircap, airpose, smartmocap, online), the demo and the command-line entry point."""
