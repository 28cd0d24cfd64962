"""MTConnect codecs, pure and sans-I/O: what the agent face (northbound) and the source (southbound) share.

- `shdr`: the adapter protocol, a line reader (bytes -> events, junk counted, never raises) and writer;
  `heartbeat`: PING/PONG timing for both ends.
- `model`: Device > Component > DataItem as plain data, and `Catalog`, the index documents are built from.
- `buffer`: the observation ring buffer with sequence numbers, /current (also `at=`) and /sample queries.
- `paths`: the `path=` XPath subset, compiled and evaluated over the device model.
- `documents` / `json_documents`: MTConnectDevices, -Streams, -Assets, -Error as MTConnect 2.4 XML and
  as cppagent's JSON version 2; `assets`: asset XML checked and stamped.

    catalog = Catalog([device])
    buffer = ObservationBuffer(catalog, instance_id=int(time.time()))
    buffer.add_unavailable(catalog.items, now)          # every data item starts UNAVAILABLE
    buffer.add_value("m1_xpos", now, 12.5)
    entries, window = buffer.current(PathIndex(catalog).select(parse_path("//Axes")))
    xml = streams_xml(catalog, entries, window, DocumentInfo(sender, now_text, model_time))
"""
