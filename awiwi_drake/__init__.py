"""awiwi_drake: model, simulate, linearise and control the DLR Awiwi hand with Drake.

After M. Chalon, *Modeling and control of an antagonistically actuated tendon
driven anthropomorphic hand*, PhD thesis, MINES ParisTech, 2013.
See docs/ARCHITECTURE.md for the map from thesis chapters to modules.
"""

__version__ = "0.1.0"
