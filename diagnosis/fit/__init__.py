"""Fitting candidate effects: the robust fit on the fast surrogate, verification and re-ranking
in PyBullet, and whether the logged motions can tell close contenders apart."""
