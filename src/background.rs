//! Background images composited behind the volume. (Being written: issue 4.)
