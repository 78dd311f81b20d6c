"""The problem specs shipped with cvxid: ``cvxid problems`` lists them, ``cvxid run NAME`` runs one."""
