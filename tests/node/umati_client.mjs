// An independent umati client (node-opcua), as a dashboard would be: run by
// tests/integration/umati/test_node_opcua.py with the gateway's endpoint.
//
// It finds the Machinery `Machines` folder by its NodeId in the Machinery namespace, every MachineTool
// below it by its TypeDefinition, reads Identification, subscribes to ActiveProgram's State/CurrentState
// and each channel's ChannelState, and to NotificationEventType events on Notification/Messages. It
// prints one JSON object a line: {"machine": …} per MachineTool found, {"ready": true} once subscribed,
// then {"value": …} and {"event": …} as they come, until its stdin closes.
import {
  OPCUAClient, MessageSecurityMode, SecurityPolicy, AttributeIds, BrowseDirection, NodeClassMask,
  ClientSubscription, ClientMonitoredItem, TimestampsToReturn, constructEventFilter, resolveNodeId,
} from "node-opcua-client";

const endpoint = process.argv[2];
const MACHINERY = "http://opcfoundation.org/UA/Machinery/";
const MACHINE_TOOL = "http://opcfoundation.org/UA/MachineTool/";
const say = (obj) => process.stdout.write(JSON.stringify(obj) + "\n");

async function children(session, nodeId) {
  const result = await session.browse({
    nodeId, browseDirection: BrowseDirection.Forward, referenceTypeId: "HierarchicalReferences",
    includeSubtypes: true, nodeClassMask: NodeClassMask.Object | NodeClassMask.Variable, resultMask: 63,
  });
  return result.references || [];
}

async function child(session, nodeId, name) {
  const found = (await children(session, nodeId)).find((r) => r.browseName.name === name);
  if (!found) throw new Error(`no ${name} under ${nodeId.toString()}`);
  return found.nodeId;
}

async function main() {
  const client = OPCUAClient.create({
    endpointMustExist: false, securityMode: MessageSecurityMode.None, securityPolicy: SecurityPolicy.None,
    connectionStrategy: { maxRetry: 3, initialDelay: 200, maxDelay: 1000 },
  });
  await client.connect(endpoint);
  const session = await client.createSession();
  const array = (await session.read({ nodeId: "i=2255", attributeId: AttributeIds.Value })).value.value;
  const machinery = array.indexOf(MACHINERY);
  const mt = array.indexOf(MACHINE_TOOL);
  const machineToolType = resolveNodeId(`ns=${mt};i=13`).toString();
  const channelType = resolveNodeId(`ns=${mt};i=16`).toString();
  const machines = resolveNodeId(`ns=${machinery};i=1001`);
  const name = (await session.read({ nodeId: machines, attributeId: AttributeIds.BrowseName })).value.value;
  const subscription = ClientSubscription.create(session, {
    requestedPublishingInterval: 50, requestedMaxKeepAliveCount: 20, requestedLifetimeCount: 600,
    maxNotificationsPerPublish: 100, publishingEnabled: true, priority: 1,
  });
  const created = [];
  const ready = (item) => created.push(new Promise((resolve, reject) => {
    item.once("initialized", resolve);
    item.once("err", (message) => reject(new Error(message)));
  }));
  const watch = async (machine, what, nodeId) => {
    const item = ClientMonitoredItem.create(
      subscription, { nodeId, attributeId: AttributeIds.Value },
      { samplingInterval: 0, discardOldest: true, queueSize: 10 }, TimestampsToReturn.Both,
    );
    ready(item);
    item.on("changed", (dv) => {
      const v = dv.value.value;
      say({ value: { machine, what, value: v && v.text !== undefined ? v.text : v, status: dv.statusCode.name } });
    });
  };
  for (const ref of await children(session, machines)) {
    if (ref.typeDefinition.toString() !== machineToolType) continue;
    const machine = ref.browseName.name;
    const identification = {};
    for (const prop of await children(session, await child(session, ref.nodeId, "Identification"))) {
      const dv = await session.read({ nodeId: prop.nodeId, attributeId: AttributeIds.Value });
      const v = dv.value.value;
      identification[prop.browseName.name] = v && v.text !== undefined ? v.text : v;
    }
    say({ machine: { name: machine, folder: `${name.namespaceIndex === machinery ? "Machinery" : "?"}:${name.name}`, identification } });
    const program = await child(session, await child(session, ref.nodeId, "Production"), "ActiveProgram");
    await watch(machine, "CurrentState", await child(session, await child(session, program, "State"), "CurrentState"));
    for (const unit of await children(session, await child(session, ref.nodeId, "Monitoring"))) {
      if (unit.typeDefinition.toString() === channelType) {
        await watch(machine, `${unit.browseName.name}/ChannelState`, await child(session, unit.nodeId, "ChannelState"));
      }
    }
    const messages = await child(session, await child(session, ref.nodeId, "Notification"), "Messages");
    const fields = ["EventType", "SourceName", "Message", "Severity", `${mt}:Identifier`];
    const events = ClientMonitoredItem.create(
      subscription, { nodeId: messages, attributeId: AttributeIds.EventNotifier },
      { samplingInterval: 0, discardOldest: true, queueSize: 100, filter: constructEventFilter(fields) },
    );
    ready(events);
    events.on("changed", (values) => {
      const [type, source, message, severity, identifier] = values.map((v) => v.value);
      say({ event: { machine, type: type && type.toString(), source, message: message && message.text, severity, identifier } });
    });
  }
  await Promise.all(created);
  say({ ready: true });
  process.stdin.resume();
  await new Promise((resolve) => process.stdin.on("end", resolve));
  await subscription.terminate();
  await session.close();
  await client.disconnect();
}

main().catch((err) => { say({ error: String(err && err.stack || err) }); process.exit(1); });
