"""What a user sees: the command line (:mod:`.cli`), the report (:mod:`.report`, its set
figures :mod:`.set_figures`), the per-tick replay (:mod:`.tick_report`) and videos
(:mod:`.render`).  The top layer: nothing in the package imports it.
"""
