"""The tables the stages write, one module per table: its columns, units and writer.

- :mod:`~holofit.tables.crop`: ``crops.csv`` and ``candidates.csv`` (written by
  :mod:`holofit.crop.stage`), and the crop stack's sidecar;
- :mod:`~holofit.tables.cropset`: reading a crop folder (crops, table, instrument);
- :mod:`~holofit.tables.prefit`: ``prefit.csv`` (written by :mod:`holofit.prefit.stage`);
- :mod:`~holofit.tables.library`: ``library.csv`` (written by :mod:`holofit.library.stage`);
- :mod:`~holofit.tables.fit`: the fit-table schema of ``initial.csv`` / ``fit.csv`` (written
  by :mod:`holofit.fit.stage` and the simulator, read by ``holofit analyze``);
- :mod:`~holofit.tables.inputs`: the prefit and library tables read back by later stages,
  checked against the crops they were made from.

Every stage table is keyed by its key columns (:mod:`holofit.batch.keys`; today
``("frame",)``).
"""
