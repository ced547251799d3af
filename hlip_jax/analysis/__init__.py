"""The error-system analysis, one pipeline with one definition of each part:

    step log → errors e_k and disturbances d_k (:mod:`.errors`)
             → masks: alive, warm-up, push window (:mod:`.masks`) → one run's samples (:mod:`.runs`)
             → split of the runs (:mod:`.splits`) → W estimator and E (:mod:`.estimators`)
             → run-level and step-level coverage with intervals over runs (:mod:`.coverage`,
               :mod:`.stats`)

:mod:`.settings` holds a sweep's ``[analysis]`` table.  The results directory's
``coverage.csv`` (:func:`hlip_jax.sweepio.store.write_coverage`), the per-scenario metrics, the
report and the CLI compose these parts.
"""
