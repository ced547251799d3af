"""hlip_jax: a batch evaluator of H-LIP step planning on underactuated bipeds (Xiong, Reher and
Ames, "Global Position Control on Underactuated Bipedal Robots: Step-to-step Dynamics
Approximation for Step Planning").

The package is layered; data flows one way, from a sweep file to the report, and a layer
imports only the layers below it (docs/architecture.md; tests/test_architecture.py checks it):

    presentation   the CLI, the report, figures, the per-tick replay, videos
    sweepio        sweep files -> configs, the chunked runner, the results directory
    simulation     the scenario configs, per-scenario arrays, the closed loop, devices
    plants | analysis
                   what walks the steps (a registry) | the error-system statistics pipeline
    core | runtime the H-LIP, sets, paths, the MPC and its ADMM QP | caches, workers, profiles
"""
