"""Reconstruction orchestration: ``reconstruct`` (:mod:`.api`) splits the field into blocks
(:mod:`.blocks`), runs each block (bank, optional registration or DAO, solve) through Dask
(:mod:`.parallel`) and stitches the results; :mod:`.commands` is its command line."""
