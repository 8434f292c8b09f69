"""Format readers: each turns one source file into DriveData (canonical columns)."""
