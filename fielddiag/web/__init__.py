"""The nicegui dashboard: pages only, no numerics.

* :mod:`fielddiag.web.app`: configuration, middleware, file route, ``serve()``.
* :mod:`fielddiag.web.security`: access token, Host check, upload size limit.
* :mod:`fielddiag.web.pages`: one module per page.
* :mod:`fielddiag.web.charts`: ECharts option dictionaries.
* :mod:`fielddiag.web.results_view`: drawing identification/diagnosis results.
* :mod:`fielddiag.web.services`: which parts of the pipeline exist (graceful degradation).
* :mod:`fielddiag.web.jobs`: long work in the background with progress.
* :mod:`fielddiag.web.live_control`: sources and recorder of a live recording.
"""
