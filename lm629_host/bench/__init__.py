"""Bench tools for a person at a board: bring-up, tuning, capture and plots, the live
scope, the wiring check and drawing."""
