"""The gateway: the HMI's door (commands, lock, programs, histories, audit) and the cyclic status."""
