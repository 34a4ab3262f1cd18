"""Wave optics: Zernike polynomials, pupils, the coded-MLA phase-space PSFs, turbulence."""
