"""Parameter studies of a fabric model on dask.distributed (``simulate sweep``).

:mod:`.spec` parses and validates a sweep, :mod:`.runner` runs it (one task per point or per
wavelength, resumable), :mod:`.cluster` starts or joins a TLS-secured cluster.
"""
