"""The simulation: typed scenario configs (:mod:`.config`) -> per-scenario arrays
(:mod:`.arrays`) -> the closed loop, a scan over steps vmapped over a batch (:mod:`.rollout`)
-> devices, blocks and processes, segment by segment (:mod:`.execution`).  Imports the core,
the runtime and the plant registry.
"""
