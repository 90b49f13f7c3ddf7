"""The Rerun recording: what ``run.rrd`` holds and how it is viewed.

``sink.py`` the Rerun sink (rows to entities), ``rrd_file.py`` the ``.rrd`` file itself (appending, footers,
rewriting, verifying), ``blueprint.py`` the viewer's layout, ``topology_view.py`` and ``reference_view.py``
the network and no-truth panels, ``notebook_view.py`` the Jupyter widget of ``ss.view(inline=True)``.
"""
