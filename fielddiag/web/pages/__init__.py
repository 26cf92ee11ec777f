"""One module per dashboard page; each exposes ``render(state, ...)``.

``sessions`` (the list), ``session`` (one recording against time), ``identify``
(before/after identification), ``diagnose`` (mismatch diagnosis), ``live`` (recording),
and ``upload`` (the CSV import panel of the sessions page).
"""
