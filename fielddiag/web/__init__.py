"""The nicegui dashboard: pages only, no numerics.

* :mod:`fielddiag.web.app`: configuration, middleware, file route, ``serve()``.
* :mod:`fielddiag.web.security`: access token, Host check, upload size limit.
* :mod:`fielddiag.web.pages`: one module per page.
* :mod:`fielddiag.web.charts`: ECharts option dictionaries.
* :mod:`fielddiag.web.results_view`: drawing identification/diagnosis results.
* :mod:`fielddiag.web.services`: the pipeline's operations the pages call (explicit
  arguments), and whether each part loads here.
* :mod:`fielddiag.web.jobs`: long work in the background with progress.
* :mod:`fielddiag.web.live_control`: the live page's choices, recorded through
  :mod:`fielddiag.virtual_drive`.
"""
