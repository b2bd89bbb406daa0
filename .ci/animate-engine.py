#!/usr/bin/env python3
"""Writes a copy of the 2CylinderEngine glTF (argv[1]) whose nodes move rigidly
with TRS channels (argv[2]): four part groups slide like pistons, the housing
turns. A real export with an animation added, for CI to check that such a file
is followed as moving instances. Standard library only."""
import json, math, struct, sys

src=sys.argv[1]
b=open(src,'rb').read()
l0,_=struct.unpack('<II',b[12:20]); j=json.loads(b[20:20+l0])
off=20+l0; l1,_=struct.unpack('<II',b[off:off+8]); binc=bytearray(b[off+8:off+8+l1])
def decompose(m):
    # column-major
    c=[m[0:3],m[4:7],m[8:11]]; t=m[12:15]
    s=[math.sqrt(sum(x*x for x in col)) for col in c]
    r=[[c[k][i]/s[k] for k in range(3)] for i in range(3)]  # r[row][col]
    det=(r[0][0]*(r[1][1]*r[2][2]-r[1][2]*r[2][1])-r[0][1]*(r[1][0]*r[2][2]-r[1][2]*r[2][0])+r[0][2]*(r[1][0]*r[2][1]-r[1][1]*r[2][0]))
    if det<0: s[0]=-s[0]; r=[[ -r[i][0], r[i][1], r[i][2]] for i in range(3)]
    tr=r[0][0]+r[1][1]+r[2][2]
    if tr>0:
        S=math.sqrt(tr+1)*2; w=0.25*S; x=(r[2][1]-r[1][2])/S; y=(r[0][2]-r[2][0])/S; z=(r[1][0]-r[0][1])/S
    elif r[0][0]>r[1][1] and r[0][0]>r[2][2]:
        S=math.sqrt(1+r[0][0]-r[1][1]-r[2][2])*2; w=(r[2][1]-r[1][2])/S; x=0.25*S; y=(r[0][1]+r[1][0])/S; z=(r[0][2]+r[2][0])/S
    elif r[1][1]>r[2][2]:
        S=math.sqrt(1+r[1][1]-r[0][0]-r[2][2])*2; w=(r[0][2]-r[2][0])/S; x=(r[0][1]+r[1][0])/S; y=0.25*S; z=(r[1][2]+r[2][1])/S
    else:
        S=math.sqrt(1+r[2][2]-r[0][0]-r[1][1])*2; w=(r[1][0]-r[0][1])/S; x=(r[0][2]+r[2][0])/S; y=(r[1][2]+r[2][1])/S; z=0.25*S
    return list(t),[x,y,z,w],s
def qmul(a,b):
    ax,ay,az,aw=a; bx,by,bz,bw=b
    return [aw*bx+ax*bw+ay*bz-az*by, aw*by-ax*bz+ay*bw+az*bx, aw*bz+ax*by-ay*bx+az*bw, aw*bw-ax*bx-ay*by-az*bz]
times=[0.0,0.5,1.0,1.5,2.0]
data=bytearray(); views=[]; accs=[]
def add(vals, typ, count, minmax=None):
    global data
    while len(data)%4: data+=b'\0'
    o=len(binc)+len(data)
    data+=struct.pack('<%df'%len(vals),*vals)
    views.append({'buffer':0,'byteOffset':o,'byteLength':4*len(vals)})
    a={'bufferView':len(j['bufferViews'])+len(views)-1,'componentType':5126,'count':count,'type':typ}
    if minmax: a['min'],a['max']=minmax
    accs.append(a); return len(j['accessors'])+len(accs)-1
tin=add(times,'SCALAR',5,([0.0],[2.0]))
channels=[]; samplers=[]
movers={1:0,4:1,7:2,10:3}
for n,k in movers.items():
    node=j['nodes'][n]
    t,q,s=decompose(node.pop('matrix')) if 'matrix' in node else ([0.0,0,0],[0.0,0,0,1],[1.0,1,1])
    node['translation'],node['rotation'],node['scale']=t,q,s
    # piston-like: up and down in y by 20 units (the engine is ~600 long),
    # a quarter period apart
    amp=20.0
    keys=[]
    for tt in times: keys+= [t[0], t[1]+amp*math.sin(math.pi*tt + k*math.pi/2), t[2]]
    out=add(keys,'VEC3',5)
    samplers.append({'input':tin,'output':out}); channels.append({'sampler':len(samplers)-1,'target':{'node':n,'path':'translation'}})
# turn node 13 (the housing's group) about its local z, pi/8 radians a second
node=j['nodes'][13]
t,q,s=decompose(node.pop('matrix')) if 'matrix' in node else ([0.0,0,0],[0.0,0,0,1],[1.0,1,1])
node['translation'],node['rotation'],node['scale']=t,q,s
keys=[]
for tt in times:
    a=math.pi*tt/8
    keys+=qmul(q,[0,0,math.sin(a/2),math.cos(a/2)])
out=add(keys,'VEC4',5)
samplers.append({'input':tin,'output':out}); channels.append({'sampler':len(samplers)-1,'target':{'node':13,'path':'rotation'}})
j['bufferViews']+=views; j['accessors']+=accs
j['animations']=[{'channels':channels,'samplers':samplers}]
newbin=binc+data
while len(newbin)%4: newbin+=b'\0'
j['buffers'][0]['byteLength']=len(newbin)
js=json.dumps(j).encode()
while len(js)%4: js+=b' '
out=struct.pack('<III',0x46546C67,2,12+8+len(js)+8+len(newbin))+struct.pack('<II',len(js),0x4E4F534A)+js+struct.pack('<II',len(newbin),0x004E4942)+newbin
open(sys.argv[2],'wb').write(out)
print('wrote', sys.argv[2], len(out))
