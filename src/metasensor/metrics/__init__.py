"""Image-quality metrics: PSNR, SSIM, slanted-edge MTF, field maps."""
