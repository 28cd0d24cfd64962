"""Authentication helpers shared by the gateway's servers (FTP inbox, later OPC UA users)."""
