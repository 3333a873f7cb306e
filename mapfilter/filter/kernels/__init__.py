"""The filter's numba kernels, fenced off from the rest of the package.

Nothing here knows a model: the two passes of the filter step (``passes``) call the models'
own compiled kernels through function pointers of fixed signatures (``MOVE_SIGNATURE``,
``LIKELIHOOD_SIGNATURE``; ``pointers`` is the one module that reaches numba's private API for
them), and draw their random numbers from a counter-based generator (``draws``). Every kernel is compiled with an explicit signature when this package is
imported: once per install, and loaded from numba's cache in one go afterwards.
"""
