"""Files: the package's own data, untrusted files read as data (YAML, npz), results written atomically, and run
directories (the lock that keeps two processes out of one, the mark of a folder this program owns)."""
