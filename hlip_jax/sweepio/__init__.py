"""Sweep I/O: a sweep file validated into scenario configs (:mod:`.sweep`), simulated chunk by
chunk (:mod:`.runner`) into a results directory (:mod:`.store`: manifest, chunks,
``summary.csv``, ``coverage.csv``); and the closed loop's benchmark (:mod:`.bench`).
"""
