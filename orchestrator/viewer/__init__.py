"""The Rerun viewer's side of a run: the recording ``run.rrd``, what it holds and how it is viewed (the files of
a run, trajectory.npz, the chunks and events.jsonl, are in ``records/``).

``sink.py`` the Rerun sink (rows to entities), ``handoff.py`` what the records hand it at a flush (row batches,
the logs deferred until then, in call order), ``rrd_file.py`` the ``.rrd`` file itself (appending, footers,
rewriting, verifying), ``blueprint.py`` the viewer's layout, ``topology_view.py`` and ``reference_view.py``
the network and no-truth panels, ``notebook_view.py`` the Jupyter widget of ``ss.view(inline=True)``.
"""
