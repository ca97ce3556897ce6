//! Pinhole orbit camera, 45° vertical view angle. (Being written: issue 4.)
