#!/usr/bin/python3
"""Plots of `isouq validate` (placeholder, being written)."""
