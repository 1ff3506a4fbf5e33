"""What to do with a posterior: ``identify`` (what grouped rankings identify), ``diagnostics`` (R-hat, ESS),
``check`` (posterior predictive check), ``calibration``, ``metrics`` (CMSE, constraint sets), ``margins``
(margin tuning), ``suggest`` (what to label next), ``export`` (ArviZ, tables) and ``plots``.
"""
