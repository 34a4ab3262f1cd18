"""Image alignment: sub-pixel shifts between images (:mod:`.shifts`) and smooth non-rigid
registration (:mod:`.nonrigid`)."""
