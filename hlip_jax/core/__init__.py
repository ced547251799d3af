"""The H-LIP core: pure functions on arrays.  The S2S dynamics, orbits and stepping gains
(:mod:`.hlip`), reference paths (:mod:`.paths`), the condensed MPC over future steps
(:mod:`.mpc`) with its tube tightening (:mod:`.robust`) and its ADMM solver (:mod:`.qp`,
:mod:`.qp_fused`), the sets (:mod:`.sets`, :mod:`.invariant`), the step log's fields and the
S2S residual (:mod:`.steplog`), identified S2S maps (:mod:`.s2s_fit`, :mod:`.s2s_model`) and the
config fields' validation metadata (:mod:`.fields`).  Imports nothing of the package above it.
"""
