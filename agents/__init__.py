# numba kernels cache by a hash of every kernel source (see truav.kernel_cache).
from truav import kernel_cache  # noqa: F401
