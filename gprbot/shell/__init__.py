"""The operator's command shell: line protocol, TCP and serial servers, client."""
