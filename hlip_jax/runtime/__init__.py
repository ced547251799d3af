"""What the program runs on: the persistent caches (:mod:`.compile_cache`, :mod:`.trace_cache`,
:mod:`.cache_files`), XLA's flags (:mod:`.xla_flags`), the GPU/CPU implementation profile
(:mod:`.impl`), worker processes (:mod:`.workers`), progress lines (:mod:`.progress`) and the
package's data files (:mod:`.resources`).  Imports nothing of the package above it.
"""
